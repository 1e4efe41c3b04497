"""Running a batched computation as a loop over chunks of the batch (lowest layer: jax only).

On XLA's CPU backend a ``vmap`` over a large batch materialises every intermediate for the
whole batch, which leaves the cache; a loop (``lax.map``) over chunks of a few rows keeps each
chunk's intermediates in it. The camera and the attention layer both batch this way inside
their ``custom_vmap`` rules.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp


def ceil_div(a: int, b: int) -> int:
    """``ceil(a / b)`` for positive ints, exactly (no float)."""
    return -(-a // b)


def map_chunks(fn: Callable[[Any], Any], args: Any, chunk: int, axis_size: int) -> Any:
    """``fn`` over consecutive chunks of ``chunk`` rows of ``args``, concatenated.

    Args:
      fn: takes a pytree like ``args`` whose leaves have a leading axis of ``chunk`` rows and
        returns a pytree whose leaves have that leading axis.
      args: a pytree whose leaves share the leading (batch) axis ``axis_size`` (``None``
        leaves are passed through as ``None``).
      chunk: rows per call of ``fn`` (capped at ``axis_size``); a last partial chunk is
        padded by repeating the batch's last row, and the padding's outputs are dropped.
      axis_size: the batch size.

    Returns:
      ``fn``'s outputs with leading axis ``axis_size``.
    """
    chunk = min(chunk, axis_size)
    n_chunks = ceil_div(axis_size, chunk)
    padded = n_chunks * chunk

    def split(x):
        if padded != axis_size:
            x = repeat_row(x, row=-1, count=padded - axis_size)
        return x.reshape((n_chunks, chunk) + x.shape[1:])

    out = jax.lax.map(fn, jax.tree.map(split, args))
    return jax.tree.map(lambda x: x.reshape((padded,) + x.shape[2:])[:axis_size], out)


def repeat_row(x: jax.Array, *, row: int, count: int) -> jax.Array:
    """``x`` ``(n, ...)`` with ``count`` copies of its row ``row`` appended: ``(n + count, ...)``.

    Pads a batch to whole chunks (:func:`map_chunks`, the last row) or to equal shares per
    device (the population evaluator, ``iap_mjx.es.rollout``, the first row); the padding's
    outputs are dropped, so which row is copied never reaches a result, and each caller keeps
    the row its compiled programs are built with.
    """
    start = row % x.shape[0]
    return jnp.concatenate([x, jnp.repeat(x[start : start + 1], count, axis=0)], axis=0)
