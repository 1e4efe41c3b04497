"""Evolution strategies: the compiled population evaluation, the update, and ``train()``.

``train(config)`` is the one call, with a :class:`iap_mjx.configs.TrainConfig` (presets in
:mod:`iap_mjx.configs`). ``OpenES`` and ``EvosaxStrategy`` are the strategies.
"""

from iap_mjx.es.components import TrainState, build, make_env_and_policy
from iap_mjx.es.results import TrainResult, evaluate_run, evaluate_run_episodes, in_condition, load_run
from iap_mjx.es.shaping import SHAPINGS, centred_ranks
from iap_mjx.es.strategy import EvosaxStrategy, OpenES, estimate_gradient
from iap_mjx.es.train import train

__all__ = [
    "EvosaxStrategy",
    "OpenES",
    "SHAPINGS",
    "TrainResult",
    "TrainState",
    "build",
    "centred_ranks",
    "estimate_gradient",
    "evaluate_run",
    "evaluate_run_episodes",
    "in_condition",
    "load_run",
    "make_env_and_policy",
    "train",
]
