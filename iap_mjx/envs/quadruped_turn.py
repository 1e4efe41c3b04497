"""``quadruped-turn``: the flat floor with a turn command, where the PMTG low level learns to
steer on command before a high level drives it.

Figure 11's hierarchy trains both levels together from a straight trot, and most of its runs'
low levels end up turning one way only (RESULTS.md, ``fig11-analysis``): a high level that sees
a wall on its left cannot make such a robot turn right. This task trains the turning first.

Per episode a command ``c ~ U(-1, 1)`` asks for a yaw rate of ``c * max_turn_rate`` rad/s
(positive: left, toward +y), that is, a heading ``theta(t) = c * max_turn_rate * t``.

- Observation ``(18,)``: ``c``, then ``quadruped-flat``'s 17 (IMU roll and pitch, angular
  velocity in the trunk frame, the 12 joint angles); the gyro's yaw rate lets a linear policy
  close the loop on the command.
- Reward: the trunk's displacement over the control step along the heading commanded at the
  step's start, capped as on the flat: ``max(-cap, min(dp . (cos theta, sin theta), cap))``. A
  robot that walks straight earns less and less as the commanded heading turns away from it;
  at ``c = 0`` the reward is ``quadruped-flat``'s exactly.
- Episode end, length, physics and action: ``quadruped-flat``'s.

The command rides in the physics state, as the course's walls do: an invisible mocap body
``command`` (no geoms) at ``(c, 0, -1)``, written from the episode's ``task_info`` after every
control step (``_sync_task``), so the reward and the observation, which see only ``mjx.Data``,
read it there.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from iap_mjx.configs.env import QuadrupedTurnConfig
from iap_mjx.envs.quadruped import QuadrupedFlat


class QuadrupedTurn(QuadrupedFlat):
    """Walk and turn at a commanded yaw rate on the flat. See the module docstring."""

    name = "quadruped-turn"
    config_class = QuadrupedTurnConfig
    config: QuadrupedTurnConfig

    def __init__(self, config: QuadrupedTurnConfig | None = None, **overrides: Any):
        super().__init__(config, **overrides)
        body = self._id(mujoco.mjtObj.mjOBJ_BODY, "command")
        self._command = int(self.mj_model.body_mocapid[body])

    def _model_spec(self) -> mujoco.MjSpec:
        spec = super()._model_spec()
        spec.worldbody.add_body(name="command", mocap=True, pos=[0.0, 0.0, -1.0])
        return spec

    def _initial_data(self, key: jax.Array) -> tuple[mjx.Data, dict]:
        body_key, command_key = jax.random.split(key)
        data, _ = super()._initial_data(body_key)
        task_info = {"command": jax.random.uniform(command_key, (), minval=-1.0, maxval=1.0)}
        return self._sync_task(data, task_info), task_info

    def _sync_task(self, data: mjx.Data, task_info: dict[str, Any]) -> mjx.Data:
        """Writes the episode's command into the ``command`` mocap body (none before one is
        drawn: the flat's own reset runs a forward pass first)."""
        if "command" not in task_info:
            return data
        position = jnp.stack([jnp.asarray(task_info["command"], jnp.float32), 0.0, -1.0])
        return data.replace(mocap_pos=data.mocap_pos.at[self._command].set(position))

    def command(self, data: mjx.Data) -> jax.Array:
        """The episode's command ``c`` in ``[-1, 1]``, ``()``."""
        return data.mocap_pos[self._command, 0]

    def heading(self, data: mjx.Data) -> jax.Array:
        """The heading (rad) commanded at ``data.time``, ``()``."""
        return self.command(data) * self.config.max_turn_rate * data.time

    def state_observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([self.command(data)[None], super().state_observation(data)])

    def step_reward(self, before: mjx.Data, after: mjx.Data) -> jax.Array:
        cap = self.config.v_cap * self.control_timestep
        theta = self.heading(before)
        along = jnp.dot(after.qpos[:2] - before.qpos[:2], jnp.stack([jnp.cos(theta), jnp.sin(theta)]))
        return jnp.clip(along, -cap, cap)
