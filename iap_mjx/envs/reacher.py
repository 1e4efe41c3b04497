"""reacher-easy: dm_control's ``suite.reacher.easy`` on MJX."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from iap_mjx.envs.dm_control_suite import reacher
from iap_mjx.envs.dmc import DmControlEnv, randomize_limited_and_rotational_joints
from iap_mjx.envs.rewards import tolerance

_BIG_TARGET = 0.05


class ReacherEasy(DmControlEnv):
    """Two-link arm; reward 1 while the finger touches the (big, 0.05) target.

    dm_control moves the target by editing the model (``geom_pos``); here the model is
    shared by the batch, so the target's x-y lives in ``State.info["target"]`` ``(2,)`` and
    is written into ``data.geom_xpos`` after every physics update (the target is a
    world geom without contacts, so this is all the physics ever reads of it). Renderers
    therefore see it where it is.

    Observation (6,): ``position`` = qpos (2), ``to_target`` = target - finger x-y (2),
    ``velocity`` = qvel (2).
    """

    name = "reacher-easy"
    domain = reacher
    n_sub_steps = 1

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._target = self._id(mujoco.mjtObj.mjOBJ_GEOM, "target")
        self._finger = self._id(mujoco.mjtObj.mjOBJ_GEOM, "finger")

    def _edit_model(self, mj_model: mujoco.MjModel) -> None:
        target = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_GEOM, "target")
        mj_model.geom_size[target, 0] = _BIG_TARGET  # dm_control's initialize_episode

    def _initial_data(self, key: jax.Array) -> tuple[mjx.Data, dict]:
        key_joints, key_angle, key_radius = jax.random.split(key, 3)
        data = mjx.make_data(self.mj_model)
        qpos = randomize_limited_and_rotational_joints(self.mj_model, key_joints, data.qpos)
        angle = jax.random.uniform(key_angle, (), minval=0.0, maxval=2 * np.pi)
        radius = jax.random.uniform(key_radius, (), minval=0.05, maxval=0.20)
        info = {"target": jnp.stack([radius * jnp.sin(angle), radius * jnp.cos(angle)])}
        return self.forward(data.replace(qpos=qpos), info), info

    def _sync_task(self, data: mjx.Data, task_info: dict) -> mjx.Data:
        if "target" not in task_info:
            raise ValueError("reacher-easy needs task_info['target'], the target's x-y (2,).")
        position = data.geom_xpos[self._target].at[:2].set(task_info["target"])
        return data.replace(geom_xpos=data.geom_xpos.at[self._target].set(position))

    def finger_to_target(self, data: mjx.Data) -> jax.Array:
        """The target's position minus the finger's, in the x-y plane: ``(2,)``."""
        return data.geom_xpos[self._target, :2] - data.geom_xpos[self._finger, :2]

    def state_observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos, self.finger_to_target(data), data.qvel])

    def reward(self, data: mjx.Data) -> jax.Array:
        radii = float(self.mj_model.geom_size[self._target, 0] + self.mj_model.geom_size[self._finger, 0])
        return tolerance(jnp.linalg.norm(self.finger_to_target(data)), (0.0, radii))
