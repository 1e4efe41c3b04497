"""cheetah-run: dm_control's ``suite.cheetah.run`` on MJX."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco import mjx

from iap_mjx.envs.dm_control_suite import cheetah
from iap_mjx.envs.dmc import DmControlEnv
from iap_mjx.envs.rewards import tolerance

_RUN_SPEED = 10.0
_SETTLE_STEPS = 200


class CheetahRun(DmControlEnv):
    """Run forward: reward ``tolerance(speed, (10, inf), margin=10, linear)``.

    Observation (17,): ``position`` = qpos[1:] (8), ``velocity`` = qvel (9).
    """

    name = "cheetah-run"
    domain = cheetah
    n_sub_steps = 1
    default_max_contacts = 10  # dm_control: <= 5 touching (tests/test_envs_contacts.py)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._speed_index = self._sensor_address("torso_subtreelinvel")

    def _initial_data(self, key: jax.Array) -> tuple[mjx.Data, dict]:
        model = self.mj_model
        if model.nq != model.njnt:
            raise ValueError("cheetah's initialisation assumes one qpos per joint.")
        limited = jnp.asarray(model.jnt_limited == 1)
        lower, upper = model.jnt_range.T
        sample = jax.random.uniform(key, (model.nq,), minval=lower, maxval=upper)
        qpos = jnp.where(limited, sample, jnp.asarray(model.qpos0, jnp.float32))
        data = mjx.make_data(model).replace(qpos=qpos)
        return self._settle(data, _SETTLE_STEPS), {}

    def speed(self, data: mjx.Data) -> jax.Array:
        """Forward speed of the torso subtree's centre of mass, ``()``."""
        return data.sensordata[self._speed_index]

    def state_observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos[1:], data.qvel])

    def reward(self, data: mjx.Data) -> jax.Array:
        return tolerance(
            self.speed(data),
            bounds=(_RUN_SPEED, float("inf")),
            margin=_RUN_SPEED,
            value_at_margin=0,
            sigmoid="linear",
        )
