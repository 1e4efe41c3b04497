"""ball_in_cup-catch: dm_control's ``suite.ball_in_cup.catch`` on MJX."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from iap_mjx.envs.dm_control_suite import ball_in_cup
from iap_mjx.envs.dmc import DmControlEnv, first_contact_free


class BallInCupCatch(DmControlEnv):
    """Swing the ball (on a string) into the cup; reward 1 while it is inside.

    Observation (8,): ``position`` = qpos (4), ``velocity`` = qvel (4).
    Control step 0.02 s = 10 physics steps of 0.002 s.
    """

    name = "ball_in_cup-catch"
    domain = ball_in_cup
    n_sub_steps = 10
    default_max_contacts = 6  # dm_control: <= 3 touching (tests/test_envs_contacts.py)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        model = self.mj_model
        self._ball_x = self._qpos_address("ball_x")
        self._ball_z = self._qpos_address("ball_z")
        self._ball_body = self._id(mujoco.mjtObj.mjOBJ_BODY, "ball")
        self._target_site = self._id(mujoco.mjtObj.mjOBJ_SITE, "target")
        ball_radius = model.geom_size[self._id(mujoco.mjtObj.mjOBJ_GEOM, "ball"), 0]
        self._inside = jnp.asarray(model.site_size[self._target_site, [0, 2]] - ball_radius)

    def _initial_data(self, key: jax.Array) -> tuple[mjx.Data, dict]:
        """dm_control's rejection sampling: redraw the ball position while it touches anything."""
        blank = mjx.make_data(self.mj_model)

        def place(key):
            key_x, key_z = jax.random.split(key)
            qpos = blank.qpos.at[self._ball_x].set(jax.random.uniform(key_x, (), minval=-0.2, maxval=0.2))
            qpos = qpos.at[self._ball_z].set(jax.random.uniform(key_z, (), minval=0.2, maxval=0.5))
            return self.forward(blank.replace(qpos=qpos))

        return first_contact_free(place, key), {}

    def ball_to_target(self, data: mjx.Data) -> jax.Array:
        """The target's position minus the ball's, in the x-z plane: ``(2,)``."""
        target = data.site_xpos[self._target_site, jnp.array([0, 2])]
        ball = data.xpos[self._ball_body, jnp.array([0, 2])]
        return target - ball

    def state_observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos, data.qvel])

    def reward(self, data: mjx.Data) -> jax.Array:
        return jnp.all(jnp.abs(self.ball_to_target(data)) < self._inside).astype(jnp.float32)
