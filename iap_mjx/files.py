"""Files written whole: a killed process or a concurrent reader sees the old file (or none) or
the new one, never half of one.

Each write goes to a temporary file beside the target, which ``os.replace`` then renames over
it (atomic within one file system). Run directories (``config.json``, metrics, ``eval.json``),
the reports' JSON and the markdown files whose sections scripts rewrite are all written this way.

What this does not do: order two writers. Two processes that each read a file, change their
part and write it whole (a RESULTS.md section, an ``eval.json`` entry) can lose one another's
change; run one report per file at a time. A process killed between creating the temporary file
and renaming it leaves that ``.<name>.<pid>.<random>.tmp`` file beside the target.
"""

from __future__ import annotations

import json
import os
import stat
import uuid
from pathlib import Path
from typing import Any


def write_atomically(path: str | os.PathLike, value: bytes) -> None:
    """Writes ``value`` to ``path`` through a temporary file in the same directory.

    A symlink at ``path`` is followed (its target is replaced, the link stays). The result has
    the permissions of the file it replaces, or for a new file those a plain write gives (the
    process's umask).
    """
    path = Path(path).resolve()
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:  # closes fd whatever happens below
            if path.exists():
                os.fchmod(fd, stat.S_IMODE(path.stat().st_mode))
            f.write(value)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def write_text(path: str | os.PathLike, text: str) -> None:
    """:func:`write_atomically` of ``text`` in UTF-8."""
    write_atomically(path, text.encode("utf-8"))


def write_json(path: str | os.PathLike, value: Any, *, indent: int = 1) -> None:
    """:func:`write_text` of ``value`` as JSON (a final newline after it)."""
    write_text(path, json.dumps(value, indent=indent) + "\n")
