"""The environment protocol every env follows (brax / MuJoCo Playground style).

An env is a value, not a singleton: ``reset(key) -> State`` and ``step(state, action) -> State``
are pure functions of their arguments (the env object only holds constants: the MJX model and
the task's static settings), so they can be ``jit``-ed, ``vmap``-ed and ``scan``-ned.
"""

from __future__ import annotations

from typing import Any, Protocol

import jax
from flax import struct
from mujoco import mjx


@struct.dataclass
class State:
    """One env's state between control steps (add a leading batch axis under ``vmap``).

    Attributes:
      data: the MJX physics state.
      obs: the observation, ``(obs_size,)`` for state observations or ``(H, W, C)`` pixels
        (a dict only for combined modes such as ``"pixels+state"``).
      reward: ``()`` float32, the reward of the last control step.
      done: ``()`` float32, 1.0 once the episode has ended (time limit or a bad state).
      metrics: named ``()`` scalars to average/sum in logs (e.g. ``"nan_terminations"``).
      info: anything else the env carries between steps (step count, RNG key, frame stack).
    """

    data: mjx.Data
    obs: Any
    reward: jax.Array
    done: jax.Array
    metrics: dict[str, jax.Array] = struct.field(default_factory=dict)
    info: dict[str, Any] = struct.field(default_factory=dict)


class Env(Protocol):
    """What the ES engine and the policies rely on."""

    @property
    def action_size(self) -> int: ...

    @property
    def observation_shape(self) -> Any: ...

    @property
    def episode_length(self) -> int:
        """Control steps per episode (after action repeat)."""
        ...

    def reset(self, key: jax.Array) -> State: ...

    def step(self, state: State, action: jax.Array) -> State: ...
