"""Type and range checks of settings, shared by every config and entry point.

A bad setting fails with a ``ValueError`` that names it and its valid values, before anything
compiles. ``True`` is an ``int`` to Python but never a size, a count or an index here, so every
integer check refuses ``bool``.
"""

from __future__ import annotations


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
