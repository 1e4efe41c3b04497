"""Type and range checks of settings, shared by every config and entry point.

A bad setting fails with a ``ValueError`` that names it and its valid values, before anything
compiles. ``True`` is an ``int`` to Python but never a size, a count or an index here, so every
integer check refuses ``bool``.
"""

from __future__ import annotations

import math


def is_int(value: object) -> bool:
    """An ``int`` that is not a ``bool``."""
    return isinstance(value, int) and not isinstance(value, bool)


def is_number(value: object) -> bool:
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
    in_range = is_number(value) and (low < value if low_open else low <= value)
    in_range = in_range and (value < high if high_open else value <= high)
    if not in_range:
        if high == math.inf and not high_open:
            valid = f"a number {'>' if low_open else '>='} {low:g}"
        elif high == math.inf:
            valid = f"a finite number {'>' if low_open else '>='} {low:g}"
        else:
            valid = f"a number in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
        raise ValueError(f"{setting} must be {valid}{f' ({unit})' if unit else ''}, got {value!r}.")
