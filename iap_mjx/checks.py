"""Type and range checks of settings, shared by every config and entry point.

A bad setting fails with a ``ValueError`` that names it and its valid values, before anything
compiles. ``True`` is an ``int`` to Python but never a size, a count or an index here, so every
integer check refuses ``bool``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TypeGuard


def is_int(value: object) -> TypeGuard[int]:
    """An ``int`` that is not a ``bool``."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_number(value: object) -> TypeGuard[int | float]:
    """An ``int`` or a ``float`` that is not a ``bool``."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def require_int(setting: str, value: object, minimum: int = 1, *, none_ok: bool = False) -> None:
    """Raises ``ValueError`` naming ``setting`` unless ``value`` is an int >= ``minimum`` (or
    ``None``, when ``none_ok``)."""
    if none_ok and value is None:
        return
    if not is_int(value) or value < minimum:
        valid = f"an int >= {minimum}" + (" or None" if none_ok else "")
        raise ValueError(f"{setting} must be {valid}, got {value!r}.")


def require_number(
    setting: str,
    value: object,
    low: float,
    high: float = math.inf,
    *,
    low_open: bool = False,
    high_open: bool = False,
    unit: str | None = None,
) -> None:
    """Raises ``ValueError`` naming ``setting`` unless ``value`` is a number in the interval
    from ``low`` to ``high`` (each end excluded when ``*_open``; ``high_open`` with the default
    ``high`` asks for a finite number). NaN is never in range."""
    in_range = (
        is_number(value)
        and (low < value if low_open else low <= value)
        and (value < high if high_open else value <= high)
    )
    if not in_range:
        if high == math.inf and not high_open:
            valid = f"a number {'>' if low_open else '>='} {low:g}"
        elif high == math.inf:
            valid = f"a finite number {'>' if low_open else '>='} {low:g}"
        else:
            valid = f"a number in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
        raise ValueError(f"{setting} must be {valid}{f' ({unit})' if unit else ''}, got {value!r}.")


def require_bool(setting: str, value: object) -> None:
    """Raises ``ValueError`` naming ``setting`` unless ``value`` is ``True`` or ``False`` (a
    command line's ``true``/``false`` are parsed to them; ``1`` or ``"yes"`` are not)."""
    if not isinstance(value, bool):
        raise ValueError(f"{setting} must be true or false, got {value!r}.")


def require_choice(setting: str, value: object, choices: Iterable[object]) -> None:
    """Raises ``ValueError`` naming ``setting`` and every valid value unless ``value`` is one
    of ``choices`` (listed in their order; a set's sorted)."""
    valid = sorted(choices) if isinstance(choices, (set, frozenset)) else list(choices)
    if not any(type(value) is type(choice) and value == choice for choice in valid):
        raise ValueError(f"{setting} must be one of {', '.join(map(str, valid))}, got {value!r}.")
