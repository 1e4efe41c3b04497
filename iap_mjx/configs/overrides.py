"""``key=value`` overrides of a ``TrainConfig``, as typed on the command line.

``es.population_size=64`` sets a field; ``iterations=50`` works too when the field name is
unique across sections; ``policy.hidden_sizes=64,64`` sets a policy option; ``env.X=...``
(X an ``EnvConfig`` field, not one of ``EnvSpec``'s own, such as ``name``) sets an env override
passed to ``iap_mjx.envs.make``, validated there against the task's config class. Values are
Python literals (``0.01``, ``true``, ``64,64``, ``'adam'``); anything else is a string. The
result is validated as a whole, so a bad value fails here with the field's name.
"""

from __future__ import annotations

import ast
import dataclasses
from collections.abc import Iterable
from typing import Any

from iap_mjx.checks import is_int
from iap_mjx.configs.env import DISTRACTION_SETTINGS
from iap_mjx.configs.training import TrainConfig

_OPEN_SECTIONS = {"policy": "options", "env": "overrides"}


def parse_value(text: str) -> Any:
    """``"0.1"`` -> 0.1, ``"true"`` -> True, ``"64,64"`` -> (64, 64), ``"adam"`` -> "adam",
    ``"None"`` or ``"null"`` -> None, ``"none"`` -> "none" (a valid string setting, e.g. the
    attention's ``scaling``)."""
    lowered = text.strip().lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    if text.strip() == "null":
        return None
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text
    return tuple(value) if isinstance(value, list) else value


def _coerce(current: Any, value: Any) -> Any:
    """Matches the type of the field's current value where that is unambiguous."""
    if isinstance(current, bool) or current is None:
        return value
    if isinstance(current, float) and is_int(value):
        return float(value)
    if isinstance(current, tuple) and not isinstance(value, tuple):
        return (value,)
    return value


def _split(path: str, config: TrainConfig) -> tuple[str, str]:
    sections = [f.name for f in dataclasses.fields(config)]
    if "." in path:
        section, _, name = path.partition(".")
        if section not in sections:
            raise ValueError(f"override {path!r}: unknown section {section!r}; valid: {sections}")
        return section, name
    owners = [s for s in sections if path in {f.name for f in dataclasses.fields(getattr(config, s))}]
    if len(owners) != 1:
        valid = sorted(f"{s}.{f.name}" for s in sections for f in dataclasses.fields(getattr(config, s)))
        why = "is ambiguous" if owners else "is not a config field"
        raise ValueError(f"override {path!r} {why}; valid keys: {valid}")
    return owners[0], path


def _parse(item: str, config: TrainConfig) -> tuple[str, str, str]:
    """``(section, name, value text)`` of the override ``item`` on ``config``."""
    if "=" not in item:
        raise ValueError(f"override {item!r} must look like key=value")
    path, _, text = item.partition("=")
    return (*_split(path.strip(), config), text)


def override_path(item: str) -> str:
    """The ``section.name`` that the override ``item`` sets (``iterations=5`` ->
    ``run.iterations``; ``policy.patch_size=2`` -> ``policy.patch_size``). A malformed item or
    an unknown key fails as in :func:`apply_overrides`."""
    section_name, name, _ = _parse(item, TrainConfig())
    return f"{section_name}.{name}"


def apply_overrides(config: TrainConfig, overrides: Iterable[str]) -> TrainConfig:
    """Returns ``config`` with every ``key=value`` in ``overrides`` applied, validated.

    The overrides are validated together, each section once with all of its changes (a key
    given twice: the last wins), so their order does not matter where settings depend on each
    other (``es.antithetic=false es.population_size=3`` in either order)."""
    changes: dict[str, dict[str, Any]] = {}
    for item in overrides:
        section_name, name, text = _parse(item, config)
        section = getattr(config, section_name)
        fields = {f.name for f in dataclasses.fields(section)}
        value = parse_value(text)
        changed = changes.setdefault(section_name, {})
        if name in fields:
            changed[name] = _coerce(getattr(section, name), value)
        elif section_name in _OPEN_SECTIONS:
            bag = _OPEN_SECTIONS[section_name]
            pairs = dict(changed.get(bag, getattr(section, bag)))
            pairs[name] = value
            changed[bag] = tuple(sorted(pairs.items()))
        else:
            path = f"{section_name}.{name}"
            raise ValueError(f"override {path!r}: {section_name} has no field {name!r}; valid: {sorted(fields)}")
    sections = {name: dataclasses.replace(getattr(config, name), **changed) for name, changed in changes.items()}
    return dataclasses.replace(config, **sections) if sections else config


CONDITION_POLICY_SETTINGS = ("policy.blind",)
"""The policy settings an evaluation condition may change besides the env: those that leave the
trained parameters as they are (``policy.blind=true``: the hierarchical policy's high level sees
a zeroed image, the trained policy with its eyes closed)."""


def check_condition(overrides: Iterable[str]) -> tuple[str, ...]:
    """``overrides`` as a tuple if every one is an ``env.<field>=<value>`` setting or one of
    :data:`CONDITION_POLICY_SETTINGS`."""
    overrides = tuple(overrides)
    allowed = lambda key: key.startswith("env.") or key in CONDITION_POLICY_SETTINGS  # noqa: E731
    bad = [item for item in overrides if not allowed(str(item).split("=", 1)[0].strip())]
    if bad:
        raise ValueError(
            "evaluation conditions set the env (env.<field>=<value>) or "
            f"{', '.join(f'{key}=<value>' for key in CONDITION_POLICY_SETTINGS)}, got {bad}"
        )
    return overrides


def apply_condition(config: TrainConfig, overrides: Iterable[str]) -> TrainConfig:
    """``config`` in another evaluation condition: ``env.<field>=<value>`` overrides and
    :data:`CONDITION_POLICY_SETTINGS` only (the policy's parameters, the ES and the loop stay
    the run's). ``env.distraction=none`` also drops the config's
    other distraction settings (``DISTRACTION_SETTINGS``), which mean nothing without one."""
    overrides = check_condition(overrides)
    settings = {key.strip(): value for key, value in (str(item).split("=", 1) for item in overrides if "=" in item)}
    if "env.distraction" in settings and parse_value(settings["env.distraction"]) in (None, "none"):
        kept = tuple((k, v) for k, v in config.env.overrides if k not in DISTRACTION_SETTINGS)
        config = dataclasses.replace(config, env=dataclasses.replace(config.env, overrides=kept))
    return apply_overrides(config, overrides)
