"""Every configuration in one place: what a run trains, the env settings, presets, overrides.

- :class:`TrainConfig` (``training.py``): a whole run, four sections: ``env`` (:class:`EnvSpec`:
  a registry name and its settings' overrides), ``policy`` (:class:`PolicySpec`: a kind and its
  options), ``es`` (:class:`ESConfig`) and ``run`` (:class:`RunConfig`).
- :class:`EnvConfig` (``env.py``): an env's own settings (action repeat, solver, observation
  mode, camera size, ...): the names ``env.<field>=...`` overrides may set.
- the Distracting Control Suite's settings (``distraction.py``): its tasks, difficulties,
  kinds and ``DistractionConfig``, which validates ``EnvConfig``'s distraction fields; its
  background sets as data (``background_sets.py``).
- the presets: rows in ``presets.py`` (with :class:`Preset`), ``dcs_presets.py`` and
  ``quadruped_presets.py``, one table of them in ``catalog.py``; ``get(name)`` gives a row's
  ``TrainConfig``.
- ``apply_overrides`` (``overrides.py``): ``key=value`` strings as typed on the command line;
  ``override_path`` names the setting one of them sets.

The settings of the parts themselves (``iap_mjx.attention.AttentionConfig``,
``iap_mjx.render.CameraConfig``) are reached through the policy options and env settings.
``iap-mjx show PRESET [key=value ...]`` prints a resolved config.
"""

from iap_mjx.configs.catalog import describe, get, lookup, names
from iap_mjx.configs.env import EnvConfig
from iap_mjx.configs.overrides import apply_overrides, override_path, parse_value
from iap_mjx.configs.presets import Preset
from iap_mjx.configs.training import EnvSpec, ESConfig, PolicySpec, RunConfig, TrainConfig

__all__ = [
    "ESConfig",
    "EnvConfig",
    "EnvSpec",
    "PolicySpec",
    "Preset",
    "RunConfig",
    "TrainConfig",
    "apply_overrides",
    "describe",
    "get",
    "lookup",
    "names",
    "override_path",
    "parse_value",
]
