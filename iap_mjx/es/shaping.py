"""Fitness shaping: raw returns ``(P,)`` -> weights ``(P,)`` for the gradient estimate.

We maximise. A NaN fitness (a diverged episode) counts as the worst: centred ranks put it
below every finite one, z-scores and the identity give it the lowest finite member's value.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from iap_mjx.configs.training import SHAPING_NAMES, one_per_name

ShapingFn = Callable[[jax.Array], jax.Array]


def _ranks(fitness: jax.Array) -> jax.Array:
    """Ranks ``0..P-1`` (float32) of ``(P,)`` fitness, NaN lowest; tied members share the mean
    of the ranks they span (scipy's ``rankdata(method="average")`` minus one).

    Sparse rewards tie often (reacher, ball_in_cup and finger score whole steps, most members
    none). Ranked by position, as ``argsort`` would, a tie is not neutral: with antithetic
    ``[eps, -eps]`` every pair tied at 0 ranks ``-eps`` above ``eps`` and steps along ``-eps``, so a
    population that all scores 0 still takes a full-sized random step. Shared ranks weight a
    tied pair equally and it cancels. Without ties these are the ordinal ranks, exactly.
    """
    rankable = jnp.where(jnp.isnan(fitness), -jnp.inf, fitness)
    ordered = jnp.sort(rankable)
    below = jnp.searchsorted(ordered, rankable, side="left")  # members strictly worse
    up_to = jnp.searchsorted(ordered, rankable, side="right")  # ... and those tied, itself included
    return (below + up_to - 1).astype(jnp.float32) / 2


def centred_ranks(fitness: jax.Array) -> jax.Array:
    """Centred ranks in ``[-0.5, 0.5]`` (Salimans et al. 2017): the best gets ``0.5``, tied
    members the same value (:func:`_ranks`), a population tied throughout ``0`` (no step).

    ``fitness`` is ``(P,)`` with ``P >= 2``; returns ``(P,)`` float32.
    """
    return _ranks(fitness) / (fitness.shape[0] - 1) - 0.5


def nan_to_worst(values: jax.Array, margin: float = 0.0) -> jax.Array:
    """``values`` with every non-finite entry replaced by the lowest finite one minus ``margin``:
    a member whose episode went NaN scores below every other."""
    finite = jnp.isfinite(values)
    return jnp.where(finite, values, jnp.min(jnp.where(finite, values, jnp.inf)) - margin)


def z_scores(fitness: jax.Array) -> jax.Array:
    """``(f - mean) / std`` over the finite entries; NaN entries get the lowest score."""
    finite = jnp.isfinite(fitness)
    safe = jnp.where(finite, fitness, 0.0)
    count = jnp.maximum(jnp.sum(finite), 1)
    mean = jnp.sum(safe) / count
    std = jnp.sqrt(jnp.sum(jnp.where(finite, (safe - mean) ** 2, 0.0)) / count)
    return nan_to_worst(jnp.where(finite, (safe - mean) / (std + 1e-8), jnp.nan))


def identity(fitness: jax.Array) -> jax.Array:
    """The raw fitness (NaN replaced by the lowest finite value)."""
    return nan_to_worst(fitness)


SHAPINGS: dict[str, ShapingFn] = one_per_name(
    SHAPING_NAMES, {"centred_rank": centred_ranks, "z_score": z_scores, "identity": identity}
)
"""The function of each ``ESConfig.shaping`` name (the names' one home:
``configs.training.SHAPING_NAMES``)."""
