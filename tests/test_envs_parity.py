"""Parity of the MJX task ports with dm_control, the reference.

For each task dm_control is reset with a fixed seed, our env starts from the same
qpos/qvel (and task variables), and both take the same 200 actions: 100 uniform in
[-1, 1], then 100 saturated at +-1. Two comparisons:

- trajectory: per-step observation and reward while the physics is smooth enough for
  float32 MJX (4 Newton iterations) and float64 MuJoCo (100) to stay together;
  the window and tolerance are stated per task;
- identical states: at every one of dm_control's 200 states, our observation and
  reward functions evaluated on the same qpos/qvel/ctrl must agree to float32 precision,
  whatever the trajectories did.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from dm_control import suite

from iap_mjx import envs

STEPS_RANDOM = 100
STEPS_SATURATED = 100


@dataclasses.dataclass(frozen=True)
class Case:
    name: str
    # Trajectory window (control steps from the start) and observation tolerance in it.
    smooth_steps: int
    obs_atol: float
    reward_atol: float


CASES = [
    Case("cheetah-run", smooth_steps=100, obs_atol=1e-3, reward_atol=1e-4),
]


def _flat(observation) -> np.ndarray:
    return np.concatenate([np.atleast_1d(v).ravel() for v in observation.values()])


def _task_info(name: str, physics) -> dict:
    if name.startswith("reacher"):
        return {"target": np.array(physics.named.model.geom_pos["target", :2])}
    return {}


def _dm_control_rollout(name: str, seed: int) -> dict:
    domain, task = name.split("-")
    env = suite.load(domain, task, task_kwargs={"random": seed})
    timestep = env.reset()
    physics = env.physics
    start = dict(
        qpos=physics.data.qpos.copy(),
        qvel=physics.data.qvel.copy(),
        obs=_flat(timestep.observation),
        info=_task_info(name, physics),
    )
    rng = np.random.default_rng(seed)
    n_act = env.action_spec().shape[0]
    actions = np.concatenate(
        [
            rng.uniform(-1, 1, (STEPS_RANDOM, n_act)),
            np.sign(rng.uniform(-1, 1, (STEPS_SATURATED, n_act))),
        ]
    )
    qpos, qvel, obs, reward = [], [], [], []
    for action in actions:
        timestep = env.step(action)
        qpos.append(physics.data.qpos.copy())
        qvel.append(physics.data.qvel.copy())
        obs.append(_flat(timestep.observation))
        reward.append(timestep.reward)
    return dict(
        start=start,
        actions=actions,
        qpos=np.array(qpos),
        qvel=np.array(qvel),
        obs=np.array(obs),
        reward=np.array(reward),
    )


@pytest.fixture(scope="module", params=CASES, ids=lambda case: case.name)
def case_and_rollouts(request):
    case = request.param
    env = envs.make(case.name)
    reference = _dm_control_rollout(case.name, seed=3)
    start = reference["start"]
    first = env.reset_to(start["qpos"], start["qvel"], **start["info"])

    @jax.jit
    def rollout(state, actions):
        def body(state, action):
            state = env.step(state, action)
            return state, (state.obs, state.reward, state.data.qpos)

        return jax.lax.scan(body, state, actions)[1]

    obs, reward, qpos = rollout(first, jnp.asarray(reference["actions"], jnp.float32))

    @jax.jit
    @jax.vmap
    def at_states(qpos, qvel, ctrl):
        state = env.reset_to(qpos, qvel, **start["info"])
        data = state.data.replace(ctrl=ctrl)
        return env.state_observation(data), env.reward(data)

    same_obs, same_reward = at_states(
        reference["qpos"], reference["qvel"], jnp.asarray(reference["actions"], jnp.float32)
    )
    ours = dict(
        first_obs=np.asarray(first.obs),
        obs=np.asarray(obs),
        reward=np.asarray(reward),
        qpos=np.asarray(qpos),
        same_obs=np.asarray(same_obs),
        same_reward=np.asarray(same_reward),
    )
    return case, reference, ours


def test_first_observation_matches(case_and_rollouts):
    _, reference, ours = case_and_rollouts
    np.testing.assert_allclose(ours["first_obs"], reference["start"]["obs"], rtol=1e-5, atol=1e-5)


def test_trajectory_matches_while_smooth(case_and_rollouts):
    case, reference, ours = case_and_rollouts
    window = slice(0, case.smooth_steps)
    np.testing.assert_allclose(ours["obs"][window], reference["obs"][window], atol=case.obs_atol)
    np.testing.assert_allclose(
        ours["reward"][window], reference["reward"][window], atol=case.reward_atol
    )


def test_observation_and_reward_functions_on_identical_states(case_and_rollouts):
    case, reference, ours = case_and_rollouts
    # float32 evaluation of float64 states: relative error of a few float32 ulps, amplified
    # by at most a few chained operations (kinematics, subtree momentum).
    np.testing.assert_allclose(ours["same_obs"], reference["obs"], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(ours["same_reward"], reference["reward"], rtol=1e-5, atol=1e-5)
