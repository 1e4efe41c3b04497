"""Fitness shaping: raw returns ``(P,)`` -> weights ``(P,)`` for the gradient estimate.

We maximise. A NaN fitness (a diverged episode) counts as the worst: centred ranks put it
below every finite one, z-scores and the identity give it the lowest finite member's value.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from iap_mjx.configs.training import SHAPINGS as SHAPING_NAMES
from iap_mjx.configs.training import one_per_name

ShapingFn = Callable[[jax.Array], jax.Array]


def _ranks(fitness: jax.Array) -> jax.Array:
    """Ordinal ranks ``0..P-1`` of ``(P,)`` fitness, NaN lowest, ties by position."""
    rankable = jnp.where(jnp.isnan(fitness), -jnp.inf, fitness)
    return jnp.argsort(jnp.argsort(rankable, stable=True), stable=True)


def centred_ranks(fitness: jax.Array) -> jax.Array:
    """Centred ranks in ``[-0.5, 0.5]`` (Salimans et al. 2017): the best gets ``0.5``.

    ``fitness`` is ``(P,)`` with ``P >= 2``; returns ``(P,)`` float32.
    """
    ranks = _ranks(fitness).astype(jnp.float32)
    return ranks / (fitness.shape[0] - 1) - 0.5


def z_scores(fitness: jax.Array) -> jax.Array:
    """``(f - mean) / std`` over the finite entries; NaN entries get the lowest score."""
    finite = jnp.isfinite(fitness)
    safe = jnp.where(finite, fitness, 0.0)
    count = jnp.maximum(jnp.sum(finite), 1)
    mean = jnp.sum(safe) / count
    std = jnp.sqrt(jnp.sum(jnp.where(finite, (safe - mean) ** 2, 0.0)) / count)
    scores = (safe - mean) / (std + 1e-8)
    return jnp.where(finite, scores, jnp.min(jnp.where(finite, scores, jnp.inf)))


def identity(fitness: jax.Array) -> jax.Array:
    """The raw fitness (NaN replaced by the lowest finite value)."""
    finite = jnp.isfinite(fitness)
    return jnp.where(finite, fitness, jnp.min(jnp.where(finite, fitness, jnp.inf)))


SHAPINGS: dict[str, ShapingFn] = one_per_name(
    SHAPING_NAMES, {"centred_rank": centred_ranks, "z_score": z_scores, "identity": identity}
)
"""The function of each ``ESConfig.shaping`` name (the names' one home:
``configs.training.SHAPINGS``)."""
