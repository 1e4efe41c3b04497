"""The preset table: every row of ``presets``, ``dcs_presets`` and ``quadruped_presets``, looked
up by name (``iap-mjx presets`` lists them). Built once at import and read-only."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from types import MappingProxyType

from iap_mjx.configs import dcs_presets, presets, quadruped_presets
from iap_mjx.configs.presets import Preset
from iap_mjx.configs.training import TrainConfig


def _table(rows: Iterable[Preset]) -> Mapping[str, Preset]:
    """``{name: row}``; a name given twice raises ``ValueError`` at import."""
    table: dict[str, Preset] = {}
    for row in rows:
        if row.name in table:
            raise ValueError(f"preset {row.name!r} is defined twice")
        table[row.name] = row
    return MappingProxyType(table)


TABLE = _table((*presets.PRESETS, *dcs_presets.PRESETS, *quadruped_presets.PRESETS))


def names() -> list[str]:
    """All preset names, sorted."""
    return sorted(TABLE)


def describe(name: str) -> str:
    """The preset's one-line description."""
    return lookup(name).description


def get(name: str) -> TrainConfig:
    """The preset's config; an unknown name raises ``ValueError`` listing the valid ones."""
    return lookup(name).config()


def lookup(name: str) -> Preset:
    """The preset's row; an unknown name raises ``ValueError`` listing the valid ones."""
    if name not in TABLE:
        raise ValueError(f"unknown preset {name!r}; valid presets: {', '.join(names())}")
    return TABLE[name]
