"""Files written whole: a killed process or a concurrent reader sees the old file (or none) or
the new one, never half of one.

Each write goes to a temporary file beside the target, which ``os.replace`` then renames over
it (atomic within one file system). Run directories (``config.json``, metrics, ``eval.json``),
the reports' JSON and the markdown files whose sections scripts rewrite are all written this way.
"""

from __future__ import annotations

import json
import os
import uuid
from pathlib import Path
from typing import Any


def write_atomically(path: str | os.PathLike, value: bytes) -> None:
    """Writes ``value`` to ``path`` through a temporary file in the same directory.

    The temporary file is created with the process's umask (as ``open`` would create
    ``path``), so the result has the permissions a plain write gives.
    """
    path = Path(path)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp")
    fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
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
