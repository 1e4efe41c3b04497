"""cartpole-swingup: dm_control's ``suite.cartpole.swingup`` on MJX (RK4, no contacts)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from iap_mjx.envs.dm_control_suite import cartpole
from iap_mjx.envs.dmc import DmControlEnv
from iap_mjx.envs.rewards import tolerance


class CartpoleSwingup(DmControlEnv):
    """Swing the pole up from hanging down and balance it; smooth reward.

    Observation (5,): ``position`` = [cart x, pole xmat zz, pole xmat xz] (3),
    ``velocity`` = qvel (2). MuJoCo's energy flag (on in dm_control's XML) is turned off:
    MJX does not compute energy, and the dynamics do not depend on it.
    """

    name = "cartpole-swingup"
    domain = cartpole
    n_sub_steps = 1

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._slider = self._qpos_address("slider")
        self._hinge = self._qpos_address("hinge_1")

    def _initial_data(self, key: jax.Array) -> tuple[mjx.Data, dict]:
        data = mjx.make_data(self.mj_model)
        nv = self.mj_model.nv
        key_pos, key_vel = jax.random.split(key)
        noise = jax.random.normal(key_pos, (self.mj_model.nq,))
        qpos = 0.1 * noise  # dm_control: extra poles (none here) get 0.1 * randn
        qpos = qpos.at[self._slider].set(0.01 * noise[self._slider])
        qpos = qpos.at[self._hinge].set(np.pi + 0.01 * noise[self._hinge])
        qvel = 0.01 * jax.random.normal(key_vel, (nv,))
        return self.forward(data.replace(qpos=qpos, qvel=qvel)), {}

    def cart_position(self, data: mjx.Data) -> jax.Array:
        """The slider's position ``()`` (m)."""
        return data.qpos[self._slider]

    def pole_angle_cosine(self, data: mjx.Data) -> jax.Array:
        """Each pole's cosine to the vertical, ``(n_poles,)`` (dm_control's ``pole_angle_cosine``)."""
        return data.xmat[2:, 2, 2]

    def state_observation(self, data: mjx.Data) -> jax.Array:
        poles = data.xmat[2:][:, jnp.array([2, 0]), 2].ravel()
        return jnp.concatenate([self.cart_position(data)[None], poles, data.qvel])

    def reward(self, data: mjx.Data) -> jax.Array:
        upright = (self.pole_angle_cosine(data) + 1) / 2
        centered = (1 + tolerance(self.cart_position(data), margin=2)) / 2
        small_control = tolerance(data.ctrl, margin=1, value_at_margin=0, sigmoid="quadratic")[0]
        small_control = (4 + small_control) / 5
        small_velocity = (1 + tolerance(data.qvel[1:], margin=5).min()) / 2
        return upright.mean() * small_control * small_velocity * centered
