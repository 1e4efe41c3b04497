"""The contact-slot limit (``EnvConfig.max_contacts``): same physics while it is not full,
and a reported saturation when it is."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from iap_mjx import envs

STEPS = 60


def _run(env, seed: int = 0):
    """Two cheetahs from ``reset``, ``STEPS`` steps of saturated alternating actions."""
    keys = jax.random.split(jax.random.key(seed), 2)
    signs = jnp.sign(jnp.sin(jnp.arange(STEPS)[:, None] / 5.0 + jnp.arange(6)[None, :]))
    actions = jnp.broadcast_to(signs, (2, STEPS, 6)).astype(jnp.float32)

    def episode(key, actions):
        state = env.reset(key)
        state, qpos = jax.lax.scan(lambda s, a: (env.step(s, a),) * 2, state, actions)
        return state, qpos.data.qpos

    return jax.jit(jax.vmap(episode))(keys, actions)


def test_limit_shrinks_the_constraint_rows():
    limited, everything = envs.make("cheetah-run"), envs.make("cheetah-run", max_contacts="all")
    assert limited.max_contacts == 10 and everything.max_contacts is None
    rows = lambda env: mjx.make_data(env.mj_model)._impl.efc_J.shape[0]  # noqa: E731
    assert rows(limited) < rows(everything)


def test_unsaturated_limit_keeps_the_trajectory():
    limited_state, limited_qpos = _run(envs.make("cheetah-run"))
    _, all_qpos = _run(envs.make("cheetah-run", max_contacts="all"))
    assert np.all(np.asarray(limited_state.metrics["contact_saturated"]) == 0)
    # float32 solver noise only: the dropped candidates were never touching.
    np.testing.assert_allclose(np.asarray(limited_qpos), np.asarray(all_qpos), atol=1e-3)


def test_a_too_small_limit_is_reported():
    state, _ = _run(envs.make("cheetah-run", max_contacts=1))
    assert np.all(np.asarray(state.metrics["contact_saturated"]) == 1)
