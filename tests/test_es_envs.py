"""A tiny pure-JAX env following the Env protocol, used by the ES tests, and tests of the
rollout against a plain Python loop over that env."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from iap_mjx.envs.base import State
from iap_mjx.es.episode import run_episode
from iap_mjx.es.normalizer import init_stats, merge_episodes
from iap_mjx.es.rollout import make_mesh, make_rollout
from iap_mjx.policies import LinearPolicy, MLPPolicy


@dataclasses.dataclass(frozen=True)
class PointMass:
    """A damped 2-D point mass pushed towards a random target; reward ``-|pos - target|``.

    ``wall``: the episode ends (``done``) once ``|pos|_inf > wall``. ``nan_wall``: past it the
    reward becomes NaN (a stand-in for diverged physics).
    """

    episode_length: int = 20
    dt: float = 0.2
    wall: float = 1e9
    nan_wall: float = 1e9

    @property
    def action_size(self) -> int:
        return 2

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (6,)

    def reset(self, key):
        pos_key, target_key = jax.random.split(key)
        pos = jax.random.uniform(pos_key, (2,), minval=-1.0, maxval=1.0)
        target = jax.random.uniform(target_key, (2,), minval=-1.0, maxval=1.0)
        data = {"pos": pos, "vel": jnp.zeros(2)}
        zero = jnp.zeros(())
        return State(
            data=data,
            obs=self._obs(data, target),
            reward=zero,
            done=zero,
            metrics={},
            info={"t": jnp.zeros((), jnp.int32), "target": target},
        )

    def _obs(self, data, target):
        return jnp.concatenate([data["pos"], data["vel"], target])

    def step(self, state, action):
        vel = 0.8 * state.data["vel"] + self.dt * jnp.clip(action, -1.0, 1.0)
        pos = state.data["pos"] + self.dt * vel
        data = {"pos": pos, "vel": vel}
        target = state.info["target"]
        reward = -jnp.linalg.norm(pos - target)
        far = jnp.max(jnp.abs(pos))
        reward = jnp.where(far > self.nan_wall, jnp.nan, reward)
        t = state.info["t"] + 1
        done = jnp.where((t >= self.episode_length) | (far > self.wall), 1.0, state.done)
        return State(
            data=data,
            obs=self._obs(data, target),
            reward=reward,
            done=done,
            metrics={},
            info={"t": t, "target": target},
        )


def python_return(env, policy, params, key):
    """Reference: a Python loop that stops at ``done``."""
    reset_key, _ = jax.random.split(key)
    state = env.reset(reset_key)
    total = 0.0
    for _ in range(env.episode_length):
        action, _ = policy.apply(params, state.obs, ())
        state = env.step(state, action)
        total += float(state.reward)
        if float(state.done) > 0:
            break
    return total


def test_rollout_matches_python_loop_with_early_termination():
    env = PointMass(episode_length=15, wall=1.2)
    policy = MLPPolicy(6, 2, (8,))
    keys = jax.random.split(jax.random.PRNGKey(3), 6)
    params = [policy.init(k) for k in keys]
    for p in params:  # push hard so that some episodes hit the wall
        p[-1]["b"] = p[-1]["b"] + 3.0
    got = [float(run_episode(env, policy, p, k, None, False).ret) for p, k in zip(params, keys)]
    want = [python_return(env, policy, p, k) for p, k in zip(params, keys)]
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    steps = [int(run_episode(env, policy, p, k, None, False).steps) for p, k in zip(params, keys)]
    assert min(steps) < env.episode_length  # early termination exercised


def test_records_mark_the_live_steps_the_return_counts():
    env = PointMass(episode_length=15, wall=1.2)
    policy = MLPPolicy(6, 2, (8,))
    keys = jax.random.split(jax.random.PRNGKey(3), 6)
    lengths = []
    for key in keys:
        params = policy.init(key)
        params[-1]["b"] = params[-1]["b"] + 3.0  # some episodes hit the wall early
        result = run_episode(env, policy, params, key, None, False, record=lambda step: {"r": step.next_state.reward})
        alive = np.asarray(result.records["alive"])
        assert alive.shape == (env.episode_length,) and np.all(np.diff(alive) <= 0)  # ones, then zeros
        assert alive.sum() == float(result.steps)
        np.testing.assert_allclose(
            np.sum(np.asarray(result.records["r"]) * alive),
            python_return(env, policy, params, key),
            rtol=1e-5,
            atol=1e-5,
        )
        lengths.append(int(alive.sum()))
    assert min(lengths) < env.episode_length  # early termination exercised


def test_nan_rewards_are_masked_and_counted():
    env = PointMass(episode_length=15, nan_wall=1.2)
    policy = LinearPolicy(6, 2)
    params = policy.init(jax.random.PRNGKey(0))
    params["b"] = jnp.array([5.0, 5.0])
    result = run_episode(env, policy, params, jax.random.PRNGKey(1), None, False)
    assert np.isfinite(float(result.ret))
    assert float(result.bad) == 1.0
    # the diverged step was simulated, so it counts among the steps taken; its reward does not
    rewards, state = [], env.reset(jax.random.split(jax.random.PRNGKey(1))[0])  # as run_episode resets
    while np.isfinite(float(state.reward)):
        state = env.step(state, policy.apply(params, state.obs, None)[0])
        rewards.append(float(state.reward))
    assert 1 < len(rewards) < env.episode_length and int(result.steps) == len(rewards)
    np.testing.assert_allclose(float(result.ret), sum(rewards[:-1]), rtol=1e-5)
    still = run_episode(env, LinearPolicy(6, 2), LinearPolicy(6, 2).init(None), jax.random.PRNGKey(1), None, False)
    assert float(still.bad) == 0.0


def python_observations(env, policy, params, key):
    """Reference: the observations a Python loop's policy acts on until ``done``, and whether
    a reward went non-finite on the way (the episode diverged)."""
    state = env.reset(jax.random.split(key)[0])  # as run_episode resets
    seen = []
    for _ in range(env.episode_length):
        seen.append(np.asarray(state.obs))
        state = env.step(state, policy.apply(params, state.obs, ())[0])
        if not np.isfinite(float(state.reward)):
            return seen, True
        if float(state.done) > 0:
            break
    return seen, False


def test_statistics_count_exactly_the_observations_they_sum():
    # some episodes diverge (NaN reward past nan_wall), some end at the wall, some run on
    env = PointMass(episode_length=15, wall=1.6, nan_wall=1.3)
    policy = LinearPolicy(6, 2)
    flat, unravel = ravel_pytree(policy.init(None))
    n = 12
    population = flat + 1.5 * jax.random.normal(jax.random.PRNGKey(4), (n, flat.shape[0]))
    keys = jax.random.split(jax.random.PRNGKey(5), n)
    prior = init_stats(6)
    episodes = jax.jit(make_rollout(env, policy, unravel, make_mesh(1), chunk_size=n, track_obs=True))(
        population, keys, prior
    )
    stats = merge_episodes(prior, episodes.steps, episodes.obs_sum, episodes.obs_sq_sum, episodes.bad)
    references = [python_observations(env, policy, unravel(p), k) for p, k in zip(population, keys)]
    diverged = np.array([d for _, d in references])
    np.testing.assert_array_equal(np.asarray(episodes.bad), diverged.astype(np.float32))
    assert 0 < diverged.sum() < n, diverged  # both kinds present
    kept = np.concatenate([np.stack(seen) for seen, d in references if not d])
    assert float(stats.count) == len(kept)
    np.testing.assert_allclose(stats.mean, kept.mean(0), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(stats.var, kept.var(0), rtol=1e-3, atol=1e-5)


def test_chunked_sharded_evaluator_matches_single_episodes():
    env = PointMass(episode_length=10)
    policy = MLPPolicy(6, 2, (4,))
    flat, unravel = ravel_pytree(policy.init(jax.random.PRNGKey(0)))
    n = 7  # odd: exercises padding over 2 devices and a ragged last chunk
    population = flat + 0.3 * jax.random.normal(jax.random.PRNGKey(1), (n, flat.shape[0]))
    keys = jax.random.split(jax.random.PRNGKey(2), n)
    stats = init_stats(6)
    rollout = make_rollout(env, policy, unravel, make_mesh(2), chunk_size=3, track_obs=True)
    result = jax.jit(rollout)(population, keys, stats)
    for i in range(n):
        one = run_episode(env, policy, unravel(population[i]), keys[i], stats, True)
        np.testing.assert_allclose(result.ret[i], one.ret, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(result.obs_sum[i], one.obs_sum, rtol=1e-5, atol=1e-5)
