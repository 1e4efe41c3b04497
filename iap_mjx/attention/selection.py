"""Top-l selection: the indices of the ``l`` best patch scores, as ``lax.top_k`` gives them."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from iap_mjx.chunks import ceil_div

TOP_L_BLOCK = 128  # scores per block of top_l's two-level search


def top_l(scores: jax.Array, l: int) -> jax.Array:
    """Indices ``(l,)`` of the ``l`` largest of the finite ``scores (L,)``, best first; ties go
    to the lower index: the same indices as ``jax.lax.top_k(scores, l)[1]``.

    Two levels: the maxima of blocks of :data:`TOP_L_BLOCK` consecutive scores (one vectorised
    pass over ``L``), then ``l`` rounds that each take the first block holding the largest
    remaining score and the first position of that score in the block (earlier picks masked),
    ``O(L + l (L / b + l b))`` in all. Inside a loop (the rollout's ``scan``) XLA's CPU backend
    lowers ``lax.top_k`` to a full stable sort of ``L`` with a comparator call per comparison:
    ``O(L log L)`` calls against these two levels' vectorised passes.
    """
    size = scores.shape[-1]
    block = min(size, TOP_L_BLOCK)
    n_blocks = ceil_div(size, block)
    if n_blocks * block != size:  # padding at the end is never picked while finite scores remain
        scores = jnp.concatenate([scores, jnp.full((n_blocks * block - size,), -jnp.inf, scores.dtype)])
    blocks = scores.reshape(n_blocks, block)
    block_max = jnp.max(blocks, axis=1)
    positions = jnp.arange(block)
    picked: list[jax.Array] = []
    for _ in range(l):
        b = jnp.argmax(block_max)
        row = blocks[b]
        for earlier in picked:
            row = jnp.where(b * block + positions == earlier, -jnp.inf, row)
        picked.append(b * block + jnp.argmax(row))
        row = jnp.where(positions == picked[-1] - b * block, -jnp.inf, row)
        block_max = block_max.at[b].set(jnp.max(row))
    return jnp.stack(picked).astype(jnp.int32)
