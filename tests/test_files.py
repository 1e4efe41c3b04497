"""Files written whole (``iap_mjx.files``): the content, a plain write's permissions (or the
replaced file's), a symlink kept, nothing left beside them, and the old file kept when a write
fails halfway."""

from __future__ import annotations

import json
import os

import pytest

from iap_mjx import files


def test_a_write_gives_the_content_and_a_plain_write_s_permissions(tmp_path):
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    files.write_text(tmp_path / "a.txt", "über\n")
    files.write_json(tmp_path / "b.json", {"k": [1, 2]}, indent=2)
    assert (tmp_path / "a.txt").read_text(encoding="utf-8") == "über\n"
    assert json.loads((tmp_path / "b.json").read_text()) == {"k": [1, 2]}
    assert (tmp_path / "b.json").read_text().endswith("\n")
    for path in ("a.txt", "b.json"):
        assert (tmp_path / path).stat().st_mode == plain.stat().st_mode, path
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.json", "plain.txt"]


class _Failing:
    """A file object whose write stores half the bytes, then fails (a full disk, a kill)."""

    def __init__(self, file):
        self.file = file

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.file.close()

    def write(self, value: bytes) -> int:
        self.file.write(value[: len(value) // 2])
        raise OSError("no space left on device")


def test_a_failed_write_keeps_the_old_file_and_leaves_nothing_beside_it(tmp_path, monkeypatch):
    path = tmp_path / "config.json"
    files.write_json(path, {"old": True})
    fdopen = os.fdopen
    monkeypatch.setattr(os, "fdopen", lambda fd, mode: _Failing(fdopen(fd, mode)))
    with pytest.raises(OSError, match="no space"):
        files.write_json(path, {"new": "x" * 1000})
    assert json.loads(path.read_text()) == {"old": True}
    assert [p.name for p in tmp_path.iterdir()] == ["config.json"]


def test_a_replaced_file_keeps_its_permissions_and_a_symlink_stays_a_link(tmp_path):
    target = tmp_path / "RESULTS.md"
    target.write_text("old\n")
    target.chmod(0o640)
    link = tmp_path / "link.md"
    link.symlink_to(target)
    files.write_text(link, "new\n")
    assert link.is_symlink() and target.read_text() == "new\n"
    assert target.stat().st_mode & 0o777 == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == ["RESULTS.md", "link.md"]
