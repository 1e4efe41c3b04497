"""Environments: MJX ports of dm_control tasks and an A1-class quadruped (``quadruped-flat``,
``quadruped-walls``, ``quadruped-gates``, ``quadruped-turn``), with the brax State convention.

``make(name, **overrides)`` builds one (see ``names()``; ``check`` validates the same
arguments without building, ``episode_length`` reads an episode's env steps); ``EnvConfig``
lists the overrides (``QuadrupedConfig`` the quadruped's, ``QuadrupedWallsConfig`` the course's, ``QuadrupedGatesConfig`` the gates
corridor's, ``QuadrupedTurnConfig`` the turn command's); ``batch`` chunks and shards a batch of
env programs for the physics benchmarks (training batches its episodes in ``iap_mjx.es.rollout``).
"""

from iap_mjx import _mjx  # noqa: F401  (imports mujoco.mjx first, quietly)
from iap_mjx.configs.env import (
    EnvConfig,
    QuadrupedConfig,
    QuadrupedGatesConfig,
    QuadrupedTurnConfig,
    QuadrupedWallsConfig,
)
from iap_mjx.envs import batch
from iap_mjx.envs.base import Env, State
from iap_mjx.envs.registry import check, check_spec, episode_length, make, make_spec, names

__all__ = [
    "Env",
    "EnvConfig",
    "QuadrupedConfig",
    "QuadrupedGatesConfig",
    "QuadrupedTurnConfig",
    "QuadrupedWallsConfig",
    "State",
    "batch",
    "check",
    "check_spec",
    "episode_length",
    "make",
    "make_spec",
    "names",
]
