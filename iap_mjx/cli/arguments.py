"""Argument types shared by the commands (counts, indices and the patch settings of Table 2),
and how a command reports a bad setting."""

from __future__ import annotations

import argparse
import sys


def count(text: str) -> int:
    """An argparse type: an int >= 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def index(text: str) -> int:
    """An argparse type: an int >= 0."""
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def settings(text: str) -> tuple[tuple[int, int], ...]:
    """An argparse type: ``"1x1,2x2,4x2"`` -> ``((1, 1), (2, 2), (4, 2))``, (patch size,
    stride) pairs."""
    pairs = []
    for part in text.split(","):
        size, _, stride = part.strip().partition("x")
        if not (size.isdigit() and stride.isdigit()):
            raise argparse.ArgumentTypeError(f"{text!r}: each setting is PATCHxSTRIDE, e.g. 1x1,2x2,4x4,4x2")
        pairs.append((int(size), int(stride)))
    return tuple(pairs)


def names(text: str) -> tuple[str, ...]:
    """An argparse type: ``"a, b"`` -> ``("a", "b")``; an empty name is refused."""
    parts = tuple(part.strip() for part in text.split(","))
    if not all(parts):
        raise argparse.ArgumentTypeError(f"{text!r}: a comma-separated list of names, none empty")
    return parts


def usage_error(error: Exception) -> int:
    """Prints ``error: <message>`` to stderr and returns the exit status of a bad setting, 2 (as
    argparse's own errors), so that a command fails before anything long starts."""
    print(f"error: {error}", file=sys.stderr)
    return 2
