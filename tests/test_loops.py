"""``loops.batched_like``: same values, every leaf batched under ``vmap`` (zero-size ones too)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from iap_mjx.loops import batched_like

# The kinds of leaves an MJX data carry holds: floats, ints, bools, scalars and zero-size arrays.
LEAVES = {
    "float": jnp.arange(6, dtype=jnp.float32).reshape(2, 3),
    "int": jnp.arange(4, dtype=jnp.int32),
    "bool": jnp.array([True, False]),
    "scalar": jnp.float32(2.5),
    "empty": jnp.zeros((0, 3), jnp.float32),
    "empty_int": jnp.zeros((0,), jnp.int32),
    "typed_key": jax.random.key(3),
}


def _values(x):
    return jax.random.key_data(x) if jnp.issubdtype(x.dtype, jax.dtypes.prng_key) else x


def test_values_shapes_and_dtypes_are_unchanged():
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    out = jax.vmap(lambda k: batched_like(LEAVES, k))(keys)
    for name, leaf in LEAVES.items():
        assert out[name].shape == (3,) + leaf.shape, name
        assert out[name].dtype == leaf.dtype, name
        expected = np.broadcast_to(_values(leaf), (3,) + _values(leaf).shape)
        np.testing.assert_array_equal(_values(out[name]), expected)


# references the loops use: raw uint32 keys, typed keys (jax.random.key, as the episodes of
# tests/test_envs_batch.py use), float state leaves, NaN or not
REFERENCES = {
    "raw_key": jax.random.split(jax.random.PRNGKey(0), 3),
    "typed_key": jax.random.split(jax.random.key(0), 3),
    "float_nan": jnp.full((3, 2), jnp.nan),
}


@pytest.mark.parametrize("reference", sorted(REFERENCES))
@pytest.mark.parametrize("name", sorted(LEAVES))
def test_every_leaf_is_batched_under_vmap(name, reference):
    """``out_axes=None`` (an unbatched output) is refused exactly when the leaf is batched."""
    keys = REFERENCES[reference]
    leaf = LEAVES[name]
    # control: the unmarked leaf is unbatched, so out_axes=None is accepted
    jax.vmap(lambda k: leaf, out_axes=None)(keys)
    with pytest.raises(ValueError, match="out_axes"):
        jax.vmap(lambda k: batched_like(leaf, k), out_axes=None)(keys)


def test_a_marked_carry_is_batched_in_one_pass(monkeypatch):
    """A scan under ``vmap`` whose carry starts unbatched is batched twice by JAX (the carry
    becomes batched in the body); marked up front, once. Counts the calls of JAX's
    ``batching.batch_jaxpr``, which the scan's batching rule makes once per pass."""
    from jax._src.interpreters import batching

    calls = []
    original = batching.batch_jaxpr

    def counting(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(batching, "batch_jaxpr", counting)

    def episode(key, mark):
        carry = (jnp.zeros(()), key)
        if mark:
            carry = batched_like(carry, key)
        return jax.lax.scan(lambda c, _: ((c[0] + c[1][0], c[1]), None), carry, length=3)[0][0]

    keys = jax.random.split(jax.random.PRNGKey(0), 3).astype(jnp.float32)
    counts = {}
    for mark in (False, True):
        calls.clear()
        jax.make_jaxpr(jax.vmap(lambda k: episode(k, mark)))(keys)
        counts[mark] = len(calls)
    assert counts == {False: 2, True: 1}
