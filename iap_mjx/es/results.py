"""What a run yields: a :class:`TrainResult` (the centre's params, a policy function ready to
act, the history), from a finished ``TrainState`` or from a run directory's latest checkpoint,
and evaluations of a run's checkpointed centre on fresh seeds (``(episodes,)`` returns, and the
env's per-episode statistics), optionally under changed env settings (a condition:
``env.background_videos=val`` ...; :func:`in_condition` moves a loaded run there).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from iap_mjx.checks import require_int
from iap_mjx.compiling import lower_afresh
from iap_mjx.configs.overrides import apply_condition, check_condition
from iap_mjx.configs.training import EVAL_SEED, TrainConfig
from iap_mjx.es import checkpoint, distributed
from iap_mjx.es.bookkeeping import restore_state
from iap_mjx.es.components import Components, TrainState, build, init_state, make_env_and_policy
from iap_mjx.es.episode import observe
from iap_mjx.es.iteration import make_centre_evaluation
from iap_mjx.es.metrics_log import read_history
from iap_mjx.es.normalizer import ObsStats
from iap_mjx.policies.base import Policy

if TYPE_CHECKING:  # iap_mjx.envs is imported only where an env is built
    from iap_mjx.envs.base import Env


@dataclasses.dataclass
class TrainResult:
    """What ``train`` returns.

    Attributes:
      params: the centre's policy params (a pytree), the ones to ship.
      obs_stats: observation statistics the policy was trained with (``None`` if unused).
      history: one dict per iteration (the columns of ``metrics.csv``).
      policy_fn: jitted ``(params, obs, policy_state) -> (action, policy_state)`` for one
        unbatched observation, with the run's observation normalisation applied; an episode
        starts from ``initial_policy_state(key)``.
      initial_policy_state: ``key -> policy_state`` for one episode (``()`` for a stateless
        policy; an LSTM's carry, a hierarchy's held command).
      config: the config trained.
      run_dir: where metrics and checkpoints went (``None`` if nowhere).
      state: the final ``TrainState``.
      env, policy: the env and policy the run was built with, for whatever runs the policy
        next (a video, an evaluation) without building them again.
    """

    params: Any
    obs_stats: ObsStats | None
    history: list[dict[str, Any]]
    policy_fn: Callable[..., Any]
    initial_policy_state: Callable[[jax.Array], Any]
    config: TrainConfig
    run_dir: Path | None
    state: TrainState
    env: Env
    policy: Policy


def make_policy_fn(parts: Components, obs_stats: ObsStats | None):
    """Jitted ``(params, obs, policy_state) -> (action, policy_state)`` for one step."""
    policy = parts.policy

    @jax.jit
    def policy_fn(params, obs, policy_state):
        return policy.apply(params, observe(obs_stats, obs), policy_state)

    return policy_fn


def result_from_state(parts: Components, state: TrainState, history, run_dir) -> TrainResult:
    """Packs a ``TrainState`` into a ``TrainResult`` (host copies of params and statistics)."""
    host = distributed.to_host(state)
    params = parts.unravel(jnp.asarray(parts.strategy.mean(host.strategy_state)))
    obs_stats = jax.tree_util.tree_map(jnp.asarray, host.obs_stats) if parts.config.es.normalize_observations else None
    return TrainResult(
        params=params,
        obs_stats=obs_stats,
        history=history,
        policy_fn=make_policy_fn(parts, obs_stats),
        initial_policy_state=parts.policy.initial_state,
        config=parts.config,
        run_dir=Path(run_dir) if run_dir is not None else None,
        state=state,
        env=parts.env,
        policy=parts.policy,
    )


def trained_config(run_dir: str | Path) -> TrainConfig:
    """A run directory's config as its checkpoint is loaded with: the stored one without the
    policy's ``low_level_init``, the file its low level started from. The checkpoint holds the
    trained parameters, and that path, relative to where the run trained, need not resolve
    where the run is loaded (``iap-mjx eval`` from another folder, a copied run directory)."""
    return without_initialisation(TrainConfig.from_dict(checkpoint.load_config(run_dir)))


def without_initialisation(config: TrainConfig) -> TrainConfig:
    """``config`` without the options that only say where training started (the policy's
    ``low_level_init``), as :func:`trained_config` builds a run."""
    options = tuple((name, value) for name, value in config.policy.options if name != "low_level_init")
    return dataclasses.replace(config, policy=dataclasses.replace(config.policy, options=options))


def load_run(run_dir: str | Path, *, env: Env | None = None, policy: Policy | None = None) -> TrainResult:
    """A run's latest checkpoint as a :class:`TrainResult` (params, ``policy_fn``, config,
    history), without training. ``env``/``policy`` as in :func:`iap_mjx.es.train.train`."""
    config = trained_config(run_dir)
    parts = build(config, env=env, policy=policy)
    state = restore_state(parts, run_dir, init_state(parts))
    return result_from_state(parts, state, read_history(run_dir), run_dir)


# what a condition whose observations no longer fit the run's parameters should do
_KEEP_SHAPES = "keep the env settings that shape what the policy sees (env.height, env.width, env.obs_mode) as trained"


def in_condition(result: TrainResult, overrides: Sequence[str]) -> TrainResult:
    """A loaded run whose config's env is moved to the condition ``overrides`` set, with the
    policy rebuilt for that env's observations (an IAP policy's parameters do not depend on
    the frame's size; a CNN's do), all checked and built before anything compiles; the run
    itself without overrides. ``ValueError`` if the run's parameters do not fit the policy on
    the condition's observations."""
    if not overrides:
        return result
    config = apply_condition(result.config, overrides)
    env, policy = make_env_and_policy(config)
    wanted = jax.eval_shape(policy.init, jax.random.PRNGKey(0))
    # jaxlib's PyTreeDef has no type information here: mypy cannot see its ==
    same_tree = jax.tree.structure(wanted) == jax.tree.structure(result.params)  # type: ignore[operator]
    fits = same_tree and all(
        a.shape == b.shape for a, b in zip(jax.tree.leaves(wanted), jax.tree.leaves(result.params))
    )
    if not fits:
        raise ValueError(
            f"the run's {config.policy.kind!r} parameters do not fit its policy on "
            f"{env.observation_shape} observations ({' '.join(overrides)}); {_KEEP_SHAPES}"
        )
    return dataclasses.replace(result, config=config, env=env, policy=policy)


def evaluate_run(
    run_dir: str | Path,
    *,
    episodes: int = 8,
    seed: int = EVAL_SEED,
    overrides: Sequence[str] = (),
    env: Env | None = None,
    policy: Policy | None = None,
    episodes_of: int | None = None,
) -> np.ndarray:
    """The ``(episodes,)`` returns of :func:`evaluate_run_episodes` (same arguments)."""
    return evaluate_run_episodes(
        run_dir, episodes=episodes, seed=seed, overrides=overrides, env=env, policy=policy, episodes_of=episodes_of
    )["return"]


def evaluate_run_episodes(
    run_dir: str | Path,
    *,
    episodes: int = 8,
    seed: int = EVAL_SEED,
    overrides: Sequence[str] = (),
    env: Env | None = None,
    policy: Policy | None = None,
    episodes_of: int | None = None,
) -> dict[str, np.ndarray]:
    """A run's latest checkpointed centre params evaluated on fresh seeds, not the training
    seeds: ``{"return": (episodes,), name: (episodes,) ...}``, one entry for each of the env's
    ``episode_metrics`` (the quadruped course's walls passed, falls, wall contacts, distance;
    nothing more for other envs).

    The episodes' keys are split from ``fold_in(fold_in(PRNGKey(seed), EVAL_STREAM),
    iteration)``, ``iteration`` the checkpoint's, as the training's own evaluation draws them.
    Runs evaluated with one ``seed`` at one iteration (Figure 11's finished runs) see the same
    episodes; another checkpoint of the same run sees others, unless ``episodes_of`` names the
    iteration whose episodes to draw instead (checkpoints of 200 and 400 iterations, both
    evaluated with ``episodes_of=200``, are compared on the same episodes). The default ``seed`` is the
    paper's tables' (:data:`EVAL_SEED`), so a finished run's evaluation here repeats the one
    its ``eval.json`` keeps. A video's ``--seed k`` episode (``PRNGKey(k)`` itself) is none of
    them.

    ``overrides``: ``env.<field>=<value>`` settings that change the evaluation's env from the
    run's, e.g. ``env.distraction=none``, ``env.dynamic=true`` or ``env.background_videos=val``
    (backgrounds never seen in training), or ``policy.blind=true`` (a hierarchical policy's
    high level given a zeroed image: ``configs.overrides.CONDITION_POLICY_SETTINGS``); the
    policy's parameters are the run's. ``env.distraction=none`` also drops the run's other
    distraction settings (``configs.overrides.apply_condition``). ``env``/``policy`` as in
    :func:`iap_mjx.es.train.train`.

    Raises:
      ValueError: a bad condition or episode count (before anything is built), or parameters
        that do not fit the policy on the condition's observations.
    """
    require_int("episodes", episodes)
    require_int("episodes_of", episodes_of, 0, none_ok=True)
    check_condition(overrides)  # before the run is read: a setting no condition may change
    config = apply_condition(trained_config(run_dir), overrides)
    if env is None:
        from iap_mjx import envs

        envs.check_spec(config.env)  # a bad env value here, before building
    parts = build(config, env=env, policy=policy)
    try:
        state = restore_state(parts, run_dir, init_state(parts))
    except checkpoint.ShapeMismatch as error:
        if not overrides:
            raise
        raise ValueError(f"{error}; here the condition {' '.join(overrides)}: {_KEEP_SHAPES}") from None
    state = state.replace(key=jax.random.PRNGKey(seed))
    if episodes_of is not None:  # the centre's parameters do not depend on the iteration count; the keys do
        state = state.replace(iteration=jnp.asarray(episodes_of, state.iteration.dtype))
    # replicated out: the episodes are sharded over the devices, and ``distributed.to_host`` reads one
    # device's copy, which would otherwise hold only that device's share of the episodes
    evaluate = jax.jit(make_centre_evaluation(parts, episodes), out_shardings=parts.replicated)
    results = lower_afresh(evaluate, state).compile()(state)
    return distributed.to_host(results)
