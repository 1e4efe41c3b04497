"""Running mean/variance of vector observations, merged from whole population rollouts."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

CLIP = 5.0


class ObsStats(struct.PyTreeNode):
    """Observation statistics: ``count`` ``()``, ``mean`` and ``var`` ``(obs_size,)`` float32."""

    count: jax.Array
    mean: jax.Array
    var: jax.Array


def init_stats(obs_size: int) -> ObsStats:
    """Zero count, mean 0 and variance 1: normalisation starts as the identity."""
    return ObsStats(
        count=jnp.zeros((), jnp.float32),
        mean=jnp.zeros((obs_size,), jnp.float32),
        var=jnp.ones((obs_size,), jnp.float32),
    )


def update_stats(stats: ObsStats, count: jax.Array, total: jax.Array, total_sq: jax.Array) -> ObsStats:
    """Merges a batch given as ``count`` ``()``, sum ``(obs,)`` and sum of squares ``(obs,)``.

    Chan et al.'s parallel update of mean and variance; a batch with ``count = 0`` is a no-op.
    """
    batch_count = jnp.maximum(count, 1.0)
    batch_mean = total / batch_count
    batch_var = jnp.maximum(total_sq / batch_count - batch_mean**2, 0.0)
    new_count = stats.count + count
    safe_count = jnp.maximum(new_count, 1.0)
    delta = batch_mean - stats.mean
    mean = stats.mean + delta * count / safe_count
    m2 = stats.var * stats.count + batch_var * count + delta**2 * stats.count * count / safe_count
    var = jnp.where(new_count > 0, m2 / safe_count, stats.var)
    return ObsStats(count=new_count, mean=mean, var=var)


def merge_episodes(
    stats: ObsStats, steps: jax.Array, obs_sum: jax.Array, obs_sq_sum: jax.Array, bad: jax.Array
) -> ObsStats:
    """Merges a batch of episodes, ``steps`` and ``bad`` ``(n,)``, sums ``(n, obs_size)``
    (``EpisodeResult``'s fields), leaving out every episode that diverged (``bad``).

    A diverged episode's ``steps`` counts the step that met the non-finite value, which its sums
    leave out; and the states before a divergence are already far from the task's. Dropped
    whole, what is merged counts exactly the observations it sums.
    """
    kept = bad == 0
    return update_stats(
        stats,
        jnp.sum(jnp.where(kept, steps, 0.0)),
        jnp.sum(jnp.where(kept[:, None], obs_sum, 0.0), axis=0),
        jnp.sum(jnp.where(kept[:, None], obs_sq_sum, 0.0), axis=0),
    )


def normalize(stats: ObsStats, obs: jax.Array) -> jax.Array:
    """``clip((obs - mean) / std, -5, 5)`` for ``(obs_size,)`` observations."""
    return jnp.clip((obs - stats.mean) / jnp.sqrt(stats.var + 1e-8), -CLIP, CLIP)
