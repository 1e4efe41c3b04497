"""``quadruped-turn``: the command drawn per episode and seen in the observation, the reward
against its closed form (the displacement along the commanded heading, capped), the flat's
reward at a zero command, and the config's checks."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from iap_mjx import envs
from iap_mjx.policies.pmtg import PMTGPolicy
from iap_mjx.robots import a1

STEPS = 40


@pytest.fixture(scope="module")
def episodes():
    """Four episodes of the PMTG policy's initial trot (it ignores the command and walks about
    0.8 m/s straight ahead): two drawn commands, a full left turn, none; the physics states
    before and after every step, the rewards and observations."""
    env = envs.make("quadruped-turn")
    # compiled: op by op, the reset's settling loop takes about two minutes
    first = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 4))
    qpos, qvel = first.data.qpos[0], first.data.qvel[0]
    reset_to = jax.jit(env.reset_to)
    pinned = [reset_to(qpos, qvel, command=c) for c in (1.0, 0.0)]
    first = jax.tree.map(lambda drawn, *fixed: jnp.concatenate([drawn[:2], jnp.stack(fixed)]), first, *pinned)
    trot = PMTGPolicy(env.observation_size)
    params = trot.init(jax.random.PRNGKey(0))
    act = jax.vmap(lambda obs, policy_state: trot.apply(params, obs, policy_state))

    def body(carry, _):
        state, policy_state = carry
        action, policy_state = act(state.obs, policy_state)
        after = jax.vmap(env.step)(state, action)
        return (after, policy_state), (
            state.data.qpos,
            state.data.time,
            after.data.qpos,
            after.reward,
            after.obs,
            after.done,
        )

    policy_state = jax.vmap(trot.initial_state)(jax.random.split(jax.random.PRNGKey(1), 4))
    _, trace = jax.jit(lambda s: jax.lax.scan(body, s, None, length=STEPS))((first, policy_state))
    return env, first, jax.tree.map(np.asarray, trace)


def test_the_command_is_drawn_per_episode_and_observed(episodes):
    env, first, (_, _, _, _, obs, _) = episodes
    commands = np.asarray(first.info["command"])
    assert env.observation_size == 18 and np.all(np.abs(commands) <= 1.0)
    assert commands[0] != commands[1] and tuple(commands[2:]) == (1.0, 0.0)
    np.testing.assert_array_equal(np.asarray(first.obs[:, 0]), commands)
    np.testing.assert_array_equal(obs[:, :, 0], np.broadcast_to(commands, (STEPS, 4)))


def test_reward_is_the_capped_displacement_along_the_commanded_heading(episodes):
    env, first, (before, time, after, reward, _, done) = episodes
    commands = np.asarray(first.info["command"])
    theta = commands * env.config.max_turn_rate * time  # (steps, episodes): the heading at each step's start
    along = np.sum((after[..., :2] - before[..., :2]) * np.stack([np.cos(theta), np.sin(theta)], -1), -1)
    cap = env.config.v_cap * a1.CONTROL_DT
    expected = np.where(np.cumsum(done, 0) - done > 0, 0.0, np.clip(along, -cap, cap))  # nothing after the end
    np.testing.assert_allclose(reward, expected, atol=1e-6)
    assert not done.any()  # the trot stays up: every step below is a live one
    np.testing.assert_allclose(time, np.broadcast_to(np.arange(STEPS)[:, None] * a1.CONTROL_DT, (STEPS, 4)), atol=1e-5)
    # at a zero command the heading stays 0: the flat's reward, the capped forward displacement
    np.testing.assert_allclose(reward[:, 3], np.clip(after[:, 3, 0] - before[:, 3, 0], -cap, cap), atol=1e-6)
    # the full left turn's heading has left the flat's behind: the two rewards differ by then
    late = slice(STEPS // 2, None)
    assert theta[-1, 2] == pytest.approx(env.config.max_turn_rate * (STEPS - 1) * a1.CONTROL_DT, rel=1e-5)
    assert not np.allclose(reward[late, 2], np.clip(after[late, 2, 0] - before[late, 2, 0], -cap, cap), atol=1e-6)


def test_turn_settings_are_checked():
    with pytest.raises(ValueError, match="max_turn_rate must be a number in"):
        envs.check("quadruped-turn", max_turn_rate=0.0)
    with pytest.raises(ValueError, match="max_turn_rate"):
        envs.check("quadruped-flat", max_turn_rate=0.5)
    assert envs.check("quadruped-turn", max_turn_rate=1.0).max_turn_rate == 1.0
