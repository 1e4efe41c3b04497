"""walker-walk: dm_control's ``suite.walker.walk`` on MJX."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from iap_mjx.envs.dm_control_suite import walker
from iap_mjx.envs.dmc import DmControlEnv, randomize_limited_and_rotational_joints
from iap_mjx.envs.rewards import tolerance

_STAND_HEIGHT = 1.2
_WALK_SPEED = 1.0


class WalkerWalk(DmControlEnv):
    """Planar walker, rewarded for standing tall and moving forward at 1 m/s.

    Observation (24,): ``orientations`` = the xx and xz entries of every body's xmat except
    the world's (14), ``height`` = torso z (1), ``velocity`` = qvel (9).
    Control step 0.025 s = 10 physics steps of 0.0025 s.
    """

    name = "walker-walk"
    domain = walker
    n_sub_steps = 10
    default_max_contacts = 12  # dm_control: <= 6 touching (tests/test_envs_contacts.py)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._torso = self._id(mujoco.mjtObj.mjOBJ_BODY, "torso")
        self._speed_index = self._sensor_address("torso_subtreelinvel")

    def _initial_data(self, key: jax.Array) -> tuple[mjx.Data, dict]:
        data = mjx.make_data(self.mj_model)
        qpos = randomize_limited_and_rotational_joints(self.mj_model, key, data.qpos)
        return self.forward(data.replace(qpos=qpos)), {}

    def torso_height(self, data: mjx.Data) -> jax.Array:
        """The torso's height ``()`` (m)."""
        return data.xpos[self._torso, 2]

    def torso_upright(self, data: mjx.Data) -> jax.Array:
        """The torso's z axis's vertical component ``()`` (1: upright)."""
        return data.xmat[self._torso, 2, 2]

    def horizontal_velocity(self, data: mjx.Data) -> jax.Array:
        """The torso subtree's forward (x) velocity ``()`` (m/s), from its ``subtreelinvel`` sensor."""
        return data.sensordata[self._speed_index]

    def state_observation(self, data: mjx.Data) -> jax.Array:
        orientations = data.xmat[1:][:, 0, jnp.array([0, 2])].ravel()
        return jnp.concatenate([orientations, self.torso_height(data)[None], data.qvel])

    def reward(self, data: mjx.Data) -> jax.Array:
        standing = tolerance(self.torso_height(data), bounds=(_STAND_HEIGHT, float("inf")), margin=_STAND_HEIGHT / 2)
        upright = (1 + self.torso_upright(data)) / 2
        stand_reward = (3 * standing + upright) / 4
        move_reward = tolerance(
            self.horizontal_velocity(data),
            bounds=(_WALK_SPEED, float("inf")),
            margin=_WALK_SPEED / 2,
            value_at_margin=0.5,
            sigmoid="linear",
        )
        return stand_reward * (5 * move_reward + 1) / 6
