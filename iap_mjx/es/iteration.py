"""One ES iteration as a pure function ``state -> (state, metrics)``, the training call that
fuses several, and the evaluation of the centre alone.

One iteration, all inside one ``jit``: ``ask`` (perturb the centre) -> evaluate every member on
``n_episodes`` episodes (its own, or with ``es.shared_episodes`` the same for all), and the
centre itself on ``run.eval_episodes`` episodes of separate seeds, in the same batch
(:mod:`iap_mjx.es.rollout`; one rollout program to compile) -> ``tell`` (shape, estimate,
update) -> merge the observation statistics.
``run.iterations_per_call`` iterations are fused by a ``lax.scan``
(:func:`make_train_call`). Each iteration's keys are ``fold_in(stream key, iteration)``, so a
resumed run continues bit for bit; the centre's evaluation seeds come from the evaluation
stream (``components.EVAL_STREAM``) the same way here and in :func:`make_centre_evaluation`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from iap_mjx.es.components import EVAL_STREAM, TRAIN_STREAM, Components, TrainState
from iap_mjx.es.episode import EpisodeResult
from iap_mjx.es.normalizer import ObsStats, merge_episodes
from iap_mjx.es.strategy import OpenES


def _stats_or_none(parts: Components, stats: ObsStats) -> ObsStats | None:
    return stats if parts.config.es.normalize_observations else None


def _stream_key(state: TrainState, stream: int) -> jax.Array:
    """The key of ``stream`` (training or evaluation) at ``state``'s iteration: the same at a
    given iteration whether the run was resumed or not."""
    return jax.random.fold_in(jax.random.fold_in(state.key, stream), state.iteration)


def _eval_keys(state: TrainState, episodes: int) -> jax.Array:
    """``(episodes,)`` keys of the centre's evaluation episodes at ``state``'s iteration."""
    return jax.random.split(_stream_key(state, EVAL_STREAM), episodes)


def _metrics(
    parts: Components,
    state: TrainState,
    strategy_state: Any,
    fitness: jax.Array,
    bad: jax.Array,
    members: EpisodeResult,
    centre: EpisodeResult,
) -> dict[str, jax.Array]:
    """An iteration's ``()`` metrics (``metrics.csv``'s columns) from the population's ``(P,)``
    fitness (NaN for a member with a bad episode) and ``(P, n_episodes)`` bad flags, the
    members' episodes (``members``), the centre's ``(eval_episodes,)`` evaluation episodes
    (``centre``: their returns and env statistics) and the strategy after the update."""
    eval_episodes = parts.config.run.eval_episodes
    finite = jnp.isfinite(fitness)
    metrics = {
        "return_mean": jnp.nanmean(fitness),
        "return_max": jnp.max(jnp.where(finite, fitness, -jnp.inf)),
        "return_min": jnp.min(jnp.where(finite, fitness, jnp.inf)),
        "return_std": jnp.nanstd(fitness),
        "nan_episodes": jnp.sum(bad),
        "contact_saturated_episodes": jnp.sum(members.saturated),
        "params_norm": jnp.linalg.norm(parts.strategy.mean(strategy_state)),
    }
    if eval_episodes:
        metrics["eval_return"] = jnp.mean(centre.ret)
        metrics["eval_return_std"] = jnp.std(centre.ret)
    for name, values in members.metrics.items():  # the env's per-episode statistics, if any
        metrics[f"{name}_mean"] = jnp.mean(values)
        if eval_episodes:
            metrics[f"eval_{name}"] = jnp.mean(centre.metrics[name])
    if isinstance(parts.strategy, OpenES):
        metrics["sigma"] = parts.strategy.sigma_at(state.iteration)
    return metrics


def make_iteration(parts: Components) -> Callable[[TrainState], tuple[TrainState, dict]]:
    """One ES iteration ``state -> (state, metrics)``; metrics are ``()`` scalars.

    ``eval_return``/``eval_return_std`` are the centre's returns at the start of the
    iteration (the params after ``state.iteration`` updates, which ``metrics.csv`` logs as
    iteration ``state.iteration + 1``) on the evaluation seeds.
    """
    es = parts.config.es
    population_size, n_episodes = es.population_size, es.n_episodes
    member_episodes = population_size * n_episodes
    eval_episodes = parts.config.run.eval_episodes

    def iteration(state: TrainState):
        """With P members, n episodes each and E evaluation episodes of the centre, over D
        parameters: one rollout of P * n + E episodes, members first."""
        ask_key, episode_key, tell_key = jax.random.split(_stream_key(state, TRAIN_STREAM), 3)
        centre = parts.strategy.mean(state.strategy_state)  # (D,)
        population, strategy_state = parts.strategy.ask(ask_key, state.strategy_state)  # (P, D)
        # (P * n + E, D): one row per episode, each member's n rows together, the centre's E last
        episode_params = jnp.concatenate(
            [
                jnp.repeat(population, n_episodes, axis=0),
                jnp.broadcast_to(centre, (eval_episodes, centre.shape[0])),
            ]
        )
        if es.shared_episodes:  # member i's episode j is episode j of every member
            member_keys = jnp.tile(jax.random.split(episode_key, n_episodes), (population_size, 1))
        else:
            member_keys = jax.random.split(episode_key, member_episodes)
        keys = jnp.concatenate([member_keys, _eval_keys(state, eval_episodes)])  # (P * n + E, 2)
        results = parts.rollout(episode_params, keys, _stats_or_none(parts, state.obs_stats))
        members = jax.tree_util.tree_map(lambda x: x[:member_episodes], results)
        centre_episodes = jax.tree_util.tree_map(lambda x: x[member_episodes:], results)  # (E,) each
        returns = members.ret.reshape(population_size, n_episodes)  # (P, n)
        bad = members.bad.reshape(population_size, n_episodes)  # (P, n): 1.0 where the physics diverged
        # (P,): a member with a diverged episode gets NaN, which the fitness shaping ranks lowest
        fitness = jnp.where(jnp.any(bad > 0, axis=1), jnp.nan, jnp.mean(returns, axis=1))
        strategy_state = parts.strategy.tell(tell_key, population, fitness, strategy_state)
        obs_stats = state.obs_stats
        if es.normalize_observations:
            obs_stats = merge_episodes(obs_stats, members.steps, members.obs_sum, members.obs_sq_sum, members.bad)
        metrics = _metrics(parts, state, strategy_state, fitness, bad, members, centre_episodes)
        new_state = TrainState(strategy_state, obs_stats, state.key, state.iteration + 1)
        return new_state, metrics

    return iteration


def make_train_call(parts: Components, count: int):
    """``count`` fused iterations: ``state -> (state, metrics with a leading (count,) axis)``."""
    iteration = make_iteration(parts)

    def call(state):
        return jax.lax.scan(lambda s, _: iteration(s), state, None, length=count)

    return call


def make_centre_evaluation(parts: Components, episodes: int):
    """``state -> {"return": (episodes,), name: (episodes,) ...}``: the centre params' returns
    on the evaluation seeds and the env's per-episode statistics (``EpisodeResult.metrics``)."""

    def evaluate(state: TrainState):
        keys = _eval_keys(state, episodes)
        centre = parts.strategy.mean(state.strategy_state)
        flat = jnp.broadcast_to(centre, (episodes, centre.shape[0]))
        result = parts.rollout(flat, keys, _stats_or_none(parts, state.obs_stats))
        return {"return": result.ret, **result.metrics}

    return evaluate
