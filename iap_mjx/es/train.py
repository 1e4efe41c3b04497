"""``train(config) -> TrainResult``: the whole ES iteration compiled, host work in between.

One iteration, all inside one ``jit``: ``ask`` (perturb the centre) -> evaluate every member on
``n_episodes`` episodes, and the centre itself on ``run.eval_episodes`` episodes of separate
seeds, in the same batch (:mod:`iap_mjx.es.rollout`; one rollout program to compile) ->
``tell`` (shape, estimate, update) -> merge the observation statistics.
``run.iterations_per_call`` iterations are fused by a ``lax.scan``; between calls the host
logs metrics, writes checkpoints and moves the progress bar. Every random draw descends from
``run.seed`` through ``fold_in(key, iteration)``, so a resumed run continues bit for bit.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct
from jax.flatten_util import ravel_pytree
from jax.sharding import NamedSharding, PartitionSpec

from iap_mjx.configs.overrides import apply_condition, check_condition
from iap_mjx.configs.training import OPEN_ES, OPTIMIZERS, ESConfig, TrainConfig
from iap_mjx.es import checkpoint
from iap_mjx.es.episode import EpisodeResult, episode_metric_names, observe
from iap_mjx.es.metrics_log import MetricsWriter, metric_columns, read_history, write_config
from iap_mjx.es.normalizer import ObsStats, init_stats, update_stats
from iap_mjx.es.rollout import make_evaluator, make_mesh, padded_share
from iap_mjx.es.shaping import SHAPINGS
from iap_mjx.es.strategy import EvosaxStrategy, OpenES, Strategy

logger = logging.getLogger(__name__)

_TRAIN_STREAM, _EVAL_STREAM, _INIT_STREAM = 0, 1, 2


@struct.dataclass
class TrainState:
    """Everything a run needs to continue: strategy state, observation statistics, the base
    key (constant) and the number of iterations done (``()`` int32)."""

    strategy_state: Any
    obs_stats: ObsStats
    key: jax.Array
    iteration: jax.Array


@dataclasses.dataclass
class TrainResult:
    """What ``train`` returns.

    Attributes:
      params: the centre's policy params (a pytree), the ones to ship.
      obs_stats: observation statistics the policy was trained with (``None`` if unused).
      history: one dict per iteration (the columns of ``metrics.csv``).
      policy_fn: jitted ``(params, obs, policy_state=()) -> (action, policy_state)`` for one
        unbatched observation, with the run's observation normalisation applied.
      initial_policy_state: ``key -> policy_state`` for one episode.
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
    env: Any
    policy: Any


@dataclasses.dataclass(frozen=True, eq=False)
class Components:
    """The built pieces of a run (shared by ``train``, ``evaluate_run`` and benchmarks)."""

    config: TrainConfig
    env: Any
    policy: Any
    strategy: Strategy
    template_params: Any
    unravel: Callable[[jax.Array], Any]
    num_dims: int
    mesh: Any
    evaluate: Callable[..., EpisodeResult]

    @property
    def steps_per_iteration(self) -> int:
        """Training env steps per iteration (members x episodes x horizon): the sample
        budget, as brax counts it."""
        es = self.config.es
        return es.population_size * es.n_episodes * self.env.episode_length

    @property
    def simulated_steps_per_iteration(self) -> int:
        """Env steps actually simulated per iteration: training, centre evaluation and the
        padding that evens out the devices' shares."""
        es, run = self.config.es, self.config.run
        rows = es.population_size * es.n_episodes + run.eval_episodes
        share = padded_share(rows, self.mesh.devices.size, run.chunk_size)
        return share * self.mesh.devices.size * self.env.episode_length


def make_sigma(es: ESConfig, iterations: int) -> float | Callable[[jax.Array], jax.Array]:
    """The perturbation std: a constant or an optax schedule over ``iterations``."""
    if es.sigma_schedule == "linear":
        return optax.linear_schedule(es.sigma, es.sigma_final, iterations)
    if es.sigma_schedule == "exponential":
        return optax.exponential_decay(es.sigma, iterations, es.sigma_final / es.sigma)
    return es.sigma


_OPTIMIZERS: dict[str, Callable[[float], optax.GradientTransformation]] = dict(
    zip(OPTIMIZERS, (optax.adam, optax.sgd, lambda learning_rate: optax.sgd(learning_rate, momentum=0.9)), strict=True)
)
"""The optax optimizer of each ``ESConfig.optimizer`` name given its learning rate, listed in
the order of ``configs.training.OPTIMIZERS`` (the names' one home): a name without an optimizer
fails at import."""


def make_optimizer(es: ESConfig) -> optax.GradientTransformation:
    """The optax optimizer named by ``es.optimizer``."""
    return _OPTIMIZERS[es.optimizer](es.learning_rate)


def make_strategy(es: ESConfig, num_dims: int, iterations: int) -> Strategy:
    """Our OpenES, or the named evosax strategy behind the adapter."""
    if es.strategy == OPEN_ES:
        return OpenES(
            population_size=es.population_size,
            sigma=make_sigma(es, iterations),
            optimizer=make_optimizer(es),
            shaping=SHAPINGS[es.shaping],
            weight_decay=es.weight_decay,
            antithetic=es.antithetic,
        )
    return EvosaxStrategy(
        name=es.strategy,
        population_size=es.population_size,
        num_dims=num_dims,
        sigma=es.sigma,
        options=es.evosax_options,
    )


def build(config: TrainConfig, *, env: Any = None, policy: Any = None, devices: Any = None) -> Components:
    """Builds env, policy, strategy and the compiled-to-be evaluators for ``config``.

    ``env``/``policy`` override the ones the config names (tests, notebooks); ``devices``
    overrides ``jax.devices()`` for the population mesh.
    """
    from iap_mjx import policies

    if env is None:
        from iap_mjx import envs

        env = envs.make(config.env.name, **dict(config.env.overrides))
    if policy is None:
        policy = policies.make(
            config.policy.kind,
            env.observation_shape,
            env.action_size,
            **dict(config.policy.options),
        )
    if config.es.normalize_observations and not (
        isinstance(env.observation_shape, tuple) and len(env.observation_shape) == 1
    ):
        raise ValueError(
            "es.normalize_observations = True needs vector observations, got shape "
            f"{env.observation_shape!r}; set es.normalize_observations=false"
        )
    template = policy.init(jax.random.fold_in(jax.random.PRNGKey(config.run.seed), _INIT_STREAM))
    flat, unravel = ravel_pytree(template)
    mesh = make_mesh(config.run.num_devices, devices)
    check_chunk_size(config.run.chunk_size, env, mesh.devices.size)
    track = config.es.normalize_observations
    evaluate = make_evaluator(env, policy, unravel, mesh, config.run.chunk_size, track)
    strategy = make_strategy(config.es, flat.shape[0], config.run.iterations)
    return Components(config, env, policy, strategy, template, unravel, flat.shape[0], mesh, evaluate)


def describe_parameters(parts: Components) -> str:
    """``"873 parameters (high 489, low 384)"``: the policy's trainable scalars, per level for a
    policy that has levels (``level_param_counts``)."""
    text = f"{parts.num_dims} parameters"
    levels = getattr(parts.policy, "level_param_counts", None)
    if levels is not None:
        text += " (" + ", ".join(f"{name} {count}" for name, count in levels(parts.template_params).items()) + ")"
    return text


def check_chunk_size(chunk_size: int, env: Any, num_devices: int) -> None:
    """Refuses ``run.chunk_size`` above the env's ``max_chunk_size`` on two or more devices,
    where a larger vmapped batch deadlocks XLA:CPU (``iap_mjx.envs.dmc.serial_lapack_batch``)."""
    limit = getattr(env, "max_chunk_size", None)
    if num_devices > 1 and limit is not None and chunk_size > limit:
        raise ValueError(
            f"run.chunk_size = {chunk_size} is too large for this env on {num_devices} devices: "
            f"valid values are 1..{limit}. With jaxlib 0.10 a larger vmapped batch splits MJX's "
            "batched Cholesky over XLA's thread pool and deadlocks XLA:CPU "
            "(see iap_mjx.envs.dmc.serial_lapack_batch)."
        )


def init_state(parts: Components) -> TrainState:
    """The state before iteration 0 (replicated over the mesh)."""
    config = parts.config
    key = jax.random.PRNGKey(config.run.seed)
    flat, _ = ravel_pytree(parts.template_params)
    obs_size = int(np.prod(parts.env.observation_shape)) if config.es.normalize_observations else 1

    def make():
        return TrainState(
            strategy_state=parts.strategy.init(jax.random.fold_in(key, _INIT_STREAM), flat),
            obs_stats=init_stats(obs_size),
            key=key,
            iteration=jnp.zeros((), jnp.int32),
        )

    replicated = NamedSharding(parts.mesh, PartitionSpec())
    return jax.jit(make, out_shardings=replicated)()


def _stats_or_none(parts: Components, stats: ObsStats) -> ObsStats | None:
    return stats if parts.config.es.normalize_observations else None


def make_iteration(parts: Components) -> Callable[[TrainState], tuple[TrainState, dict]]:
    """One ES iteration ``state -> (state, metrics)``; metrics are ``()`` scalars.

    ``eval_return``/``eval_return_std`` are the centre's returns at the start of the
    iteration (the params after ``iteration - 1`` updates) on the evaluation seeds.
    """
    es = parts.config.es
    population_size, n_episodes = es.population_size, es.n_episodes
    members = population_size * n_episodes
    eval_episodes = parts.config.run.eval_episodes

    def iteration(state: TrainState):
        key = jax.random.fold_in(jax.random.fold_in(state.key, _TRAIN_STREAM), state.iteration)
        ask_key, episode_key, tell_key = jax.random.split(key, 3)
        centre = parts.strategy.mean(state.strategy_state)
        population, strategy_state = parts.strategy.ask(ask_key, state.strategy_state)
        flat = jnp.concatenate(
            [
                jnp.repeat(population, n_episodes, axis=0),
                jnp.broadcast_to(centre, (eval_episodes, centre.shape[0])),
            ]
        )
        keys = jnp.concatenate([jax.random.split(episode_key, members), _eval_keys(state, eval_episodes)])
        everything = parts.evaluate(flat, keys, _stats_or_none(parts, state.obs_stats))
        result = jax.tree_util.tree_map(lambda x: x[:members], everything)
        eval_returns = everything.ret[members:]
        returns = result.ret.reshape(population_size, n_episodes)
        bad = result.bad.reshape(population_size, n_episodes)
        fitness = jnp.where(jnp.any(bad > 0, axis=1), jnp.nan, jnp.mean(returns, axis=1))
        strategy_state = parts.strategy.tell(tell_key, population, fitness, strategy_state)
        obs_stats = state.obs_stats
        if es.normalize_observations:
            obs_stats = update_stats(
                obs_stats, jnp.sum(result.steps), jnp.sum(result.obs_sum, 0), jnp.sum(result.obs_sq_sum, 0)
            )
        finite = jnp.isfinite(fitness)
        metrics = {
            "return_mean": jnp.nanmean(fitness),
            "return_max": jnp.max(jnp.where(finite, fitness, -jnp.inf)),
            "return_min": jnp.min(jnp.where(finite, fitness, jnp.inf)),
            "return_std": jnp.nanstd(fitness),
            "nan_episodes": jnp.sum(bad),
            "contact_saturated_episodes": jnp.sum(result.saturated),
            "params_norm": jnp.linalg.norm(parts.strategy.mean(strategy_state)),
        }
        if eval_episodes:
            metrics["eval_return"] = jnp.mean(eval_returns)
            metrics["eval_return_std"] = jnp.std(eval_returns)
        for name, values in result.metrics.items():  # the env's per-episode statistics, if any
            metrics[f"{name}_mean"] = jnp.mean(values)
            if eval_episodes:
                metrics[f"eval_{name}"] = jnp.mean(everything.metrics[name][members:])
        if isinstance(parts.strategy, OpenES):
            metrics["sigma"] = parts.strategy.sigma_at(state.iteration)
        new_state = TrainState(strategy_state, obs_stats, state.key, state.iteration + 1)
        return new_state, metrics

    return iteration


def make_train_call(parts: Components, count: int):
    """``count`` fused iterations: ``state -> (state, metrics with a leading (count,) axis)``."""
    iteration = make_iteration(parts)

    def call(state):
        return jax.lax.scan(lambda s, _: iteration(s), state, None, length=count)

    return call


def _eval_keys(state: TrainState, episodes: int | None = None) -> jax.Array:
    key = jax.random.fold_in(jax.random.fold_in(state.key, _EVAL_STREAM), state.iteration)
    return jax.random.split(key, episodes) if episodes is not None else key


def make_centre_evaluation(parts: Components, episodes: int, *, with_metrics: bool = False):
    """``state -> returns (episodes,)`` of the centre params on the evaluation seeds; with
    ``with_metrics``, ``{"return": (episodes,), name: (episodes,) ...}`` with the env's
    per-episode statistics (``EpisodeResult.metrics``) too."""

    def evaluate(state: TrainState):
        keys = jax.random.split(_eval_keys(state), episodes)
        centre = parts.strategy.mean(state.strategy_state)
        flat = jnp.broadcast_to(centre, (episodes, centre.shape[0]))
        result = parts.evaluate(flat, keys, _stats_or_none(parts, state.obs_stats))
        return {"return": result.ret, **result.metrics} if with_metrics else result.ret

    return evaluate


def _scalar(x) -> float:
    return float(np.asarray(x.addressable_data(0)) if isinstance(x, jax.Array) else x)


def make_policy_fn(parts: Components, obs_stats: ObsStats | None):
    """Jitted ``(params, obs, policy_state=()) -> (action, policy_state)`` for one step."""
    policy = parts.policy

    @jax.jit
    def policy_fn(params, obs, policy_state=()):
        return policy.apply(params, observe(obs_stats, obs), policy_state)

    return policy_fn


def result_from_state(parts: Components, state: TrainState, history, run_dir) -> TrainResult:
    """Packs a ``TrainState`` into a ``TrainResult`` (host copies of params and statistics)."""
    host = checkpoint.to_host(state)
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


def _restore(parts: Components, run_dir, state: TrainState) -> TrainState:
    step, host_state = checkpoint.restore(run_dir, state)
    replicated = NamedSharding(parts.mesh, PartitionSpec())
    restored = jax.tree_util.tree_map(
        lambda like, x: jax.device_put(np.asarray(x, dtype=like.dtype), replicated),
        state,
        host_state,
    )
    logger.info("resumed from checkpoint %d in %s", step, run_dir)
    return restored


def _check_resumable(config: TrainConfig, stored: TrainConfig, run_dir) -> None:
    """Resuming must not change the run: only ``run.iterations`` (unless a sigma schedule
    spans it), ``run.tensorboard`` and ``run.max_minutes`` may differ."""

    def comparable(c: TrainConfig) -> dict:
        flat = c.to_dict()
        if c.es.sigma_schedule == "constant":  # else sigma would jump at the resumed iteration
            flat["run"].pop("iterations")
        flat["run"].pop("tensorboard")
        flat["run"].pop("max_minutes")
        return flat

    ours, theirs = comparable(config), comparable(stored)
    differ = [
        f"{section}.{name}: checkpoint {theirs[section][name]!r}, now {value!r}"
        for section in ours
        for name, value in ours[section].items()
        if theirs[section].get(name) != value
    ]
    if differ:
        raise ValueError(
            f"{run_dir} holds a checkpoint of a different config (" + "; ".join(differ) + "); use another run directory"
        )


class CompiledCalls:
    """The training call (:func:`make_train_call`) compiled once per number of fused
    iterations (a run's last call may fuse fewer), and the seconds spent compiling."""

    def __init__(self, parts: Components):
        self.parts = parts
        self.programs: dict[int, Any] = {}
        self.seconds = 0.0

    def get(self, count: int, state: TrainState) -> Any:
        """The call fusing ``count`` iterations, compiled for ``state``'s shapes on first use."""
        if count not in self.programs:
            config = self.parts.config
            logger.info(
                "compiling the ES iteration (%s members x %s env steps; a program "
                "compiled once is loaded from the compilation cache afterwards)",
                config.es.population_size * config.es.n_episodes,
                self.parts.env.episode_length,
            )
            replicated = NamedSharding(self.parts.mesh, PartitionSpec())
            start = time.perf_counter()
            call = jax.jit(make_train_call(self.parts, count), out_shardings=replicated)
            self.programs[count] = call.lower(state).compile()
            seconds = time.perf_counter() - start
            logger.info("compiled in %.0f s", seconds)
            self.seconds += seconds
        return self.programs[count]


def metric_rows(
    parts: Components, done: int, metrics: dict[str, np.ndarray], run_s: float, compile_s: float
) -> list[dict[str, Any]]:
    """One row per iteration of a call that started after ``done`` iterations: its metrics
    (``(count,)`` each, on the host), the sample budget spent and the call's timings."""
    count = len(next(iter(metrics.values())))
    return [
        {
            "iteration": done + i + 1,
            "env_steps": (done + i + 1) * parts.steps_per_iteration,
            **{name: float(value[i]) for name, value in metrics.items()},
            "env_steps_per_s": parts.simulated_steps_per_iteration * count / run_s,
            "run_s": run_s / count,
            "compile_s": compile_s,
            "parameters": parts.num_dims,
        }
        for i in range(count)
    ]


def training_call_with_timing(
    parts: Components, calls: CompiledCalls, state: TrainState, done: int, count: int
) -> tuple[TrainState, list[dict[str, Any]]]:
    """Runs ``count`` fused iterations from ``state`` (``done`` iterations in): the new state
    and the iterations' metric rows (:func:`metric_rows`)."""
    call = calls.get(count, state)
    tick = time.perf_counter()
    new_state, metrics = call(state)
    metrics = checkpoint.to_host(metrics)
    run_s = time.perf_counter() - tick
    return new_state, metric_rows(parts, done, metrics, run_s, calls.seconds)


def start_state(parts: Components, run_dir: str | Path | None) -> tuple[TrainState, int]:
    """The state a run starts from and its iterations done: ``run_dir``'s latest checkpoint
    (its config checked against ours), else the state before iteration 0."""
    state = init_state(parts)
    if run_dir is None or checkpoint.latest_step(run_dir) is None:
        return state, 0
    _check_resumable(parts.config, TrainConfig.from_dict(checkpoint.load_config(run_dir)), run_dir)
    state = _restore(parts, run_dir, state)
    return state, int(_scalar(state.iteration))


@dataclasses.dataclass
class Reporter:
    """Where each iteration's metrics row goes: the run's ``history``, its metrics files
    (``writer``, the primary process only), ``progress_fn`` and the progress ``bar``."""

    history: list[dict[str, Any]]
    writer: MetricsWriter | None
    bar: Any
    progress_fn: Callable[[dict[str, Any]], None] | None
    started: float

    @classmethod
    def open(
        cls,
        parts: Components,
        run_dir: str | Path | None,
        start: int,
        started: float,
        *,
        progress: bool,
        progress_fn: Callable[[dict[str, Any]], None] | None,
    ) -> Reporter:
        """Writes the run's config and opens its metrics files, keeping the rows up to
        iteration ``start`` (a resumed run's checkpoint); ``started`` is the run's
        ``time.perf_counter()`` at its start."""
        config = parts.config
        primary = jax.process_index() == 0
        if run_dir is not None and primary:
            write_config(run_dir, config.to_dict())
        columns = metric_columns(episode_metric_names(parts.env))
        writer = (
            MetricsWriter(run_dir, start if start else None, config.run.tensorboard, columns=columns)
            if run_dir is not None and primary
            else None
        )
        history = list(writer.history) if writer else (read_history(run_dir, start) if run_dir else [])
        bar = None
        if progress and primary:
            from tqdm.auto import tqdm

            bar = tqdm(total=config.run.iterations, initial=start, desc="ES", unit="it")
        return cls(history, writer, bar, progress_fn, started)

    def write(self, rows: list[dict[str, Any]]) -> None:
        """Stamps each row with the run's wall time and hands it to every destination."""
        for row in rows:
            row["wall_s"] = time.perf_counter() - self.started
            self.history.append(row)
            if self.writer:
                self.writer.write(row)
            if self.progress_fn is not None:
                self.progress_fn(row)

    def advance(self, rows: list[dict[str, Any]]) -> None:
        """Moves the bar past ``rows``' iterations, showing the last one's returns."""
        if self.bar is not None:
            self.bar.update(len(rows))
            self.bar.set_postfix(
                ret=f"{rows[-1]['return_mean']:.1f}", eval=f"{rows[-1].get('eval_return', float('nan')):.1f}"
            )

    def close(self) -> None:
        """Closes the bar and the metrics files (a run ends, or is interrupted)."""
        if self.bar is not None:
            self.bar.close()
        if self.writer:
            self.writer.close()


def past_time_limit(run: Any, started: float) -> bool:
    """Whether ``run.max_minutes`` (0: none) have passed since ``started`` (compile included)."""
    return bool(run.max_minutes) and time.perf_counter() - started > 60 * run.max_minutes


def checkpoint_due(run: Any, done: int, out_of_time: bool) -> bool:
    """Whether to save a checkpoint after ``done`` iterations: at the end of the run (all
    iterations, or the time limit) and every ``run.checkpoint_every`` iterations."""
    return done == run.iterations or out_of_time or bool(run.checkpoint_every and done % run.checkpoint_every == 0)


def train(
    config: TrainConfig,
    *,
    run_dir: str | Path | None = None,
    progress: bool = True,
    env: Any = None,
    policy: Any = None,
    devices: Any = None,
    progress_fn: Callable[[dict[str, Any]], None] | None = None,
) -> TrainResult:
    """Trains ``config``'s policy on its env with ES; resumes from ``run_dir`` if it holds a
    checkpoint.

    Args:
      config: the whole configuration (validated on construction).
      run_dir: where metrics (``metrics.jsonl``/``.csv``, TensorBoard) and checkpoints go;
        ``None`` keeps everything in memory.
      progress: show a ``tqdm`` progress bar.
      env, policy: use these instead of the ones the config names.
      devices: the devices to shard the population over (default ``jax.devices()``).
      progress_fn: called with each iteration's metrics row.

    Returns a :class:`TrainResult`. ``KeyboardInterrupt`` saves a checkpoint of the last
    finished iteration (when ``run_dir`` is set) and is re-raised.
    """
    started = time.perf_counter()
    run = config.run
    if run.max_minutes and jax.process_count() > 1:
        raise ValueError(
            "run.max_minutes must be 0 with several processes (each process's "
            "clock would decide on its own when to stop)"
        )
    parts = build(config, env=env, policy=policy, devices=devices)
    state, start = start_state(parts, run_dir)
    reporter = Reporter.open(parts, run_dir, start, started, progress=progress, progress_fn=progress_fn)
    logger.info("policy %r: %s", config.policy.kind, describe_parameters(parts))
    calls = CompiledCalls(parts)
    config_dict = config.to_dict()
    done = saved = start
    try:
        while done < run.iterations:
            count = min(run.iterations_per_call, run.iterations - done)
            new_state, rows = training_call_with_timing(parts, calls, state, done, count)
            reporter.write(rows)
            state, done = new_state, done + count  # only once its rows are written
            reporter.advance(rows)
            out_of_time = past_time_limit(run, started)
            if run_dir is not None and checkpoint_due(run, done, out_of_time):
                checkpoint.save(run_dir, done, state, config_dict)
                saved = done
            if out_of_time:
                logger.info("run.max_minutes = %s reached after %d iterations", run.max_minutes, done)
                break
    except KeyboardInterrupt:
        if run_dir is not None and done > saved:
            logger.warning("interrupted: saving checkpoint %d", done)
            checkpoint.save(run_dir, done, state, config_dict)
        raise
    finally:
        reporter.close()
    return result_from_state(parts, state, reporter.history, run_dir)


def load_run(run_dir: str | Path, *, env: Any = None, policy: Any = None) -> TrainResult:
    """A run's latest checkpoint as a :class:`TrainResult` (params, ``policy_fn``, config,
    history), without training. ``env``/``policy`` as in :func:`train`."""
    config = TrainConfig.from_dict(checkpoint.load_config(run_dir))
    parts = build(config, env=env, policy=policy)
    state = _restore(parts, run_dir, init_state(parts))
    return result_from_state(parts, state, read_history(run_dir), run_dir)


def evaluate_run(
    run_dir: str | Path,
    *,
    episodes: int = 8,
    seed: int = 12345,
    overrides: Sequence[str] = (),
    env: Any = None,
    policy: Any = None,
) -> np.ndarray:
    """Returns ``(episodes,)`` returns of a run's latest checkpointed centre params on fresh
    seeds (derived from ``seed``, not the training seeds).

    ``overrides``: ``env.<field>=<value>`` settings that change the evaluation's env from the
    run's, e.g. ``env.distraction=none``, ``env.dynamic=true`` or ``env.background_videos=val``
    (backgrounds never seen in training); the policy and its parameters are the run's.
    ``env.distraction=none`` also drops the run's other distraction settings
    (``configs.overrides.apply_condition``).
    """
    return evaluate_run_episodes(run_dir, episodes=episodes, seed=seed, overrides=overrides, env=env, policy=policy)[
        "return"
    ]


def evaluate_run_episodes(
    run_dir: str | Path,
    *,
    episodes: int = 8,
    seed: int = 12345,
    overrides: Sequence[str] = (),
    env: Any = None,
    policy: Any = None,
) -> dict[str, np.ndarray]:
    """:func:`evaluate_run` with the env's per-episode statistics: ``{"return": (episodes,),
    name: (episodes,) ...}`` for each of the env's ``episode_metrics`` (the quadruped course's
    walls passed, falls, wall contacts, distance; nothing more for other envs)."""
    if not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes = {episodes!r} must be an int >= 1")
    check_condition(overrides)
    config = apply_condition(TrainConfig.from_dict(checkpoint.load_config(run_dir)), overrides)
    if env is None:
        from iap_mjx import envs

        envs.check(config.env.name, **dict(config.env.overrides))  # a bad condition fails here
    config = dataclasses.replace(config, run=dataclasses.replace(config.run, eval_episodes=episodes))
    parts = build(config, env=env, policy=policy)
    state = _restore(parts, run_dir, init_state(parts))
    state = state.replace(key=jax.random.PRNGKey(seed))
    # replicated out: the episodes are sharded over the devices, and ``to_host`` reads one
    # device's copy, which would otherwise hold only that device's share of the episodes
    replicated = NamedSharding(parts.mesh, PartitionSpec())
    results = jax.jit(make_centre_evaluation(parts, episodes, with_metrics=True), out_shardings=replicated)(state)
    return checkpoint.to_host(results)
