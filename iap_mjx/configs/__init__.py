"""Named, frozen, validated configurations: presets and ``key=value`` overrides.

The dataclasses themselves live in :mod:`iap_mjx.es.config` (``train`` needs them, and a
lower layer never imports a higher one); they are re-exported here.
"""

from iap_mjx.configs.overrides import apply_overrides, parse_value
from iap_mjx.configs import pixel_presets  # noqa: F401  (registers the pixel presets)
from iap_mjx.configs.presets import describe, get, names, register
from iap_mjx.es.config import EnvConfig, ESConfig, PolicyConfig, RunConfig, TrainConfig

__all__ = [
    "ESConfig", "EnvConfig", "PolicyConfig", "RunConfig", "TrainConfig", "apply_overrides",
    "describe", "get", "names", "parse_value", "register",
]
