"""The environment protocol every env follows (brax / MuJoCo Playground style).

An env is a value, not a singleton: ``reset(key) -> State`` and ``step(state, action) -> State``
are pure functions of their arguments (the env object only holds constants: the MJX model and
the task's static settings), so they can be ``jit``-ed, ``vmap``-ed and ``scan``-ned.
"""

from __future__ import annotations

from typing import Any, Protocol

import jax
import mujoco
from flax import struct
from mujoco import mjx


class State(struct.PyTreeNode):
    """One env's state between env steps (add a leading batch axis under ``vmap``).

    Attributes:
      data: the MJX physics state.
      obs: the observation, ``(obs_size,)`` for state observations or ``(H, W, C)`` pixels
        (a dict only for combined modes such as ``"pixels+state"``).
      reward: ``()`` float32, the reward of the last env step (summed over its action repeat).
      done: ``()`` float32, 1.0 once the episode has ended (time limit or a bad state).
      metrics: named ``()`` scalars to average/sum in logs (e.g. ``"nan_terminations"``).
      info: anything else the env carries between steps (the step count, task variables such
        as reacher's ``"target"``, the distraction's draw).
    """

    data: mjx.Data
    obs: Any
    reward: jax.Array
    done: jax.Array
    metrics: dict[str, jax.Array] = struct.field(default_factory=dict)
    info: dict[str, Any] = struct.field(default_factory=dict)


class Env(Protocol):
    """What the ES engine and the policies rely on.

    One ``step`` is one action: a dm_control task with action repeat ``k`` simulates ``k`` of its
    control steps in it (``episode_length`` and ``metrics.csv``'s ``env_steps`` count actions).

    Optional members, read where present (an env without them still trains):

    - ``max_chunk_size``: the most episodes one device may ``vmap`` at once (``train`` refuses a
      larger ``run.chunk_size`` on two or more devices; the MJX tasks set it:
      :func:`iap_mjx.envs.dmc.serial_lapack_batch`).
    - ``episode_metrics``: names of per-episode statistics the final ``State.metrics`` holds
      (the quadruped course's ``walls_passed`` ...), logged as ``metrics.csv`` columns.
    - ``State.metrics["nan_terminations"]`` (the env ended a diverged state itself) and
      ``["contact_saturated"]`` (every MJX contact slot filled): counted per iteration.
    - For videos (``iap_mjx.viz.recording``, ``iap_mjx.viz.video``): ``mj_model``
      (:class:`ModelEnv`: a state env is rendered from it), ``obs_mode`` and ``channels`` (a pixel env,
      :class:`iap_mjx.envs.pixels.PixelEnv`), ``video_camera_id`` (a scene camera to draw the
      pixel view into), ``control_timestep`` and ``config.action_repeat`` (the frame rate);
      ``camera_options`` (``CameraConfig`` fields ``with_pixels`` gets from ``envs.make``).
    - ``geom_map`` (:class:`iap_mjx.envs.pixels.GeomMapping`): ``iap-mjx attended``'s tallies.
    """

    @property
    def action_size(self) -> int:
        """The length of an action, a ``(action_size,)`` float32 vector in ``[-1, 1]``."""
        ...

    @property
    def observation_shape(self) -> Any:
        """``State.obs``'s shape: a tuple for an array (``(17,)`` a state vector, ``(H, W, C)``
        a frame), or a dict of tuples for several (``{"pixels": (H, W, C), "state": (n,)}``)."""
        ...

    @property
    def episode_length(self) -> int:
        """Env steps (actions) per episode, after action repeat."""
        ...

    def reset(self, key: jax.Array) -> State:
        """An episode's first state from a PRNG key (``()`` typed key or ``(2,)`` uint32): one
        episode, unbatched; ``vmap`` it over keys for a batch."""
        ...

    def step(self, state: State, action: jax.Array) -> State:
        """The state after one ``(action_size,)`` action, ``done`` 1.0 once the episode has
        ended (the rollout counts nothing after it; the MJX tasks also hold a done state still,
        so that a batch runs to a fixed horizon)."""
        ...


class ModelEnv(Env, Protocol):
    """An env simulated from a MuJoCo model, as every env of this package is: what a camera
    (:class:`iap_mjx.envs.pixels.PixelEnv`) and the distractions are built on besides
    :class:`Env`."""

    @property
    def mj_model(self) -> mujoco.MjModel:
        """The MuJoCo model the physics steps (the MJX model is built from it)."""
        ...
