"""Named sections of a markdown file (RESULTS.md, BENCHMARKS.md) that scripts rewrite in place,
and the cells their tables share."""

from __future__ import annotations

import re
import shutil
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from iap_mjx.files import write_text


def tracked_copy(image: Path, markdown: Path, section: str) -> Path:
    """Copies ``image`` (a figure, or any file the section cites, e.g. fig8's ``timings.json``)
    to ``<markdown's folder>/experiments/<section>/`` and returns the copy's path relative to
    ``markdown``: the section's link to it.

    Runs write their figures into an output folder that git ignores (``results/``); the copy
    puts the figure a committed markdown file shows in a tracked folder beside it.
    """
    folder = Path(markdown).resolve().parent
    target = folder / "experiments" / section / Path(image).name
    target.parent.mkdir(parents=True, exist_ok=True)
    if Path(image).resolve() != target:
        shutil.copyfile(image, target)
    return target.relative_to(folder)


def mean_std(values: list[float], digits: int = 1) -> str:
    """A table cell ``"mean ± std"`` of ``values`` (e.g. one number per seed), ``"-"`` if none."""
    return f"{np.mean(values):.{digits}f} ± {np.std(values):.{digits}f}" if len(values) else "-"


def check_section_name(section: str, example: str) -> None:
    """``ValueError`` unless ``section`` can name a RESULTS.md section and an ``experiments/``
    folder: lower-case letters, digits and dashes (``example``: one the message shows)."""
    if not isinstance(section, str) or not re.fullmatch(r"[a-z0-9][a-z0-9-]*", section):
        raise ValueError(f"section = {section!r} must be lower-case letters, digits and dashes, e.g. {example}")


def _section_pattern(name: str) -> re.Pattern:
    """``<!-- BEGIN name -->``, the section's text (group ``body``), ``<!-- END name -->``."""
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    return re.compile(re.escape(begin) + "\n?(?P<body>.*?)\n?" + re.escape(end), re.S)


def write_section(path: Path, name: str, body: str, *, title: str = "# Benchmarks") -> None:
    """Replaces the text between ``<!-- BEGIN name -->`` and ``<!-- END name -->`` in ``path``.

    The section is appended when absent (``title`` starts a file that does not exist yet), so
    every script owns only its own part of the file.
    """
    path = Path(path)
    block = f"<!-- BEGIN {name} -->\n{body.rstrip()}\n<!-- END {name} -->"
    text = path.read_text(encoding="utf-8") if path.exists() else f"{title}\n"
    pattern = _section_pattern(name)
    text = pattern.sub(lambda _: block, text) if pattern.search(text) else text.rstrip() + "\n\n" + block + "\n"
    write_text(path, text)


def read_section(path: Path, name: str) -> str | None:
    """The text :func:`write_section` put between ``name``'s markers in ``path`` (``None``:
    no such section)."""
    found = _section_pattern(name).search(Path(path).read_text(encoding="utf-8"))
    return None if found is None else found.group("body")


def reproduce_command(figure: str, options: Iterable[str], *, out: Path, results: Path) -> str:
    """The ``iap-mjx reproduce`` command line that rewrites a figure's RESULTS.md section:
    ``options`` (overrides first, then the figure's own flags), then ``--out`` and ``--results``
    (``results``' file name: the command runs beside it)."""
    return " ".join([f"iap-mjx reproduce {figure}", *options, f"--out {out}", f"--results {Path(results).name}"])


def write_results_section(path: Path, name: str, body: str) -> None:
    """:func:`write_section` for RESULTS.md: a new file starts with ``# Results``."""
    write_section(path, name, body, title="# Results")
