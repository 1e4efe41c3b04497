"""Chunked and sharded batches of envs (``iap_mjx.envs.batch``)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.sharding import Mesh

from iap_mjx import envs
from iap_mjx.envs import batch
from iap_mjx.es.episode import run_episode


@dataclasses.dataclass(frozen=True)
class _LinearPolicy:
    """``tanh(params @ obs)``, params ``(action_size, obs_size)``; no per-episode state."""

    def initial_state(self, key):
        return ()

    def apply(self, params, obs, policy_state):
        return jnp.tanh(params @ obs), policy_state


def test_chunked_vmap_equals_vmap():
    fn = lambda x, y: (jnp.sin(x) * y.sum(), x + 1)  # noqa: E731
    x = jnp.arange(12.0)
    y = jnp.arange(36.0).reshape(12, 3)
    expected = jax.vmap(fn)(x, y)
    got = jax.jit(batch.chunked_vmap(fn, 4))(x, y)
    jax.tree.map(np.testing.assert_array_equal, got, expected)
    with pytest.raises(ValueError, match="multiple"):
        batch.chunked_vmap(fn, 5)(x, y)


@pytest.mark.slow
def test_population_of_1024_envs_in_chunks_over_two_devices():
    """The size at which one plain vmap hung XLA CPU: 1024 envs, here chunked and sharded.

    reacher-easy (cheapest reset and step) and 8-step episodes keep this within CI time;
    the program shapes (2 devices x 4 chunks of 128) are those of a full population.
    The result must match the same envs run in one small plain vmap, up to the float
    rounding that a different vectorisation width brings.
    """
    assert len(jax.devices()) >= 2, "tests/conftest.py sets up two CPU devices"
    env = envs.make("reacher-easy")
    n = 1024
    keys = jax.random.split(jax.random.key(1), n)
    params = 0.3 * jax.random.normal(jax.random.key(2), (n, env.action_size, env.observation_size))
    mesh = Mesh(np.array(jax.devices()[:2]), (batch.BATCH_AXIS,))

    def episode(p, k):
        return run_episode(env, _LinearPolicy(), p, k, steps=8)

    run = jax.jit(batch.shard(batch.chunked_vmap(episode, 128), mesh))
    out = jax.block_until_ready(run(params, keys))
    assert out.ret.shape == (n,)
    assert np.all(np.isfinite(np.asarray(out.ret)))
    np.testing.assert_array_equal(out.bad, np.zeros(n))  # no bad state, flagged by the env or not
    # Spot-check 16 members against a plain 16-wide vmap.
    picks = np.arange(0, n, n // 16)
    small = jax.jit(batch.chunked_vmap(episode, 16))(params[picks], keys[picks])
    np.testing.assert_allclose(out.ret[picks], small.ret, rtol=1e-4, atol=1e-4)
