"""The host's work between compiled training calls: where a run starts (resume from its latest
checkpoint, its config checked), the compiled calls and their timing, each iteration's metrics
row and where it goes, and when to checkpoint or stop.

Nothing here is traced: the compiled programs come from :func:`iap_mjx.es.iteration.make_train_call`,
and a call's metrics arrive on the host as ``(count,)`` arrays, one row per iteration.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from iap_mjx.compiling import lower_afresh
from iap_mjx.configs.training import OPEN_ES, ESConfig, RunConfig, TrainConfig
from iap_mjx.es import checkpoint, distributed
from iap_mjx.es.components import Components, TrainState, init_state
from iap_mjx.es.episode import episode_metric_names
from iap_mjx.es.iteration import make_train_call
from iap_mjx.es.metrics_log import MetricsWriter, metric_columns, read_history, write_config

logger = logging.getLogger(__name__)


def restore_state(parts: Components, run_dir, state: TrainState) -> TrainState:
    """``run_dir``'s latest checkpoint, shaped and typed like ``state`` and replicated over the
    mesh."""
    step, host_state = checkpoint.restore(run_dir, state)
    restored = jax.tree_util.tree_map(
        lambda like, x: jax.device_put(np.asarray(x, dtype=like.dtype), parts.replicated),
        state,
        host_state,
    )
    logger.info("restored checkpoint %d of %s", step, run_dir)
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


def check_resumable(config: TrainConfig, run_dir: str | Path | None) -> None:
    """``ValueError`` if ``run_dir`` holds a checkpoint that ``config`` cannot resume (what may
    differ: :func:`_check_resumable`); nothing to check in a directory without one. Reads files
    only, so a caller can refuse a run before anything compiles."""
    if run_dir is not None and checkpoint.latest_step(run_dir) is not None:
        _check_resumable(config, TrainConfig.from_dict(checkpoint.load_config(run_dir)), run_dir)


def start_state(parts: Components, run_dir: str | Path | None) -> tuple[TrainState, int]:
    """The state a run starts from and its iterations done: ``run_dir``'s latest checkpoint
    (its config checked against ours), else the state before iteration 0."""
    state = init_state(parts)
    if run_dir is None or checkpoint.latest_step(run_dir) is None:
        return state, 0
    check_resumable(parts.config, run_dir)
    state = restore_state(parts, run_dir, state)
    done = int(distributed.to_host(state.iteration))
    logger.info("resuming training after iteration %d", done)
    return state, done


class CompiledCalls:
    """The training call (:func:`~iap_mjx.es.iteration.make_train_call`) compiled once per
    number of fused iterations (a run's last call may fuse fewer), and the seconds spent
    compiling."""

    def __init__(self, parts: Components):
        self.parts = parts
        self.programs: dict[int, Any] = {}
        self.seconds = 0.0

    def get(self, count: int, state: TrainState) -> Any:
        """The call fusing ``count`` iterations, compiled for ``state``'s shapes on first use."""
        if count not in self.programs:
            config = self.parts.config
            logger.info(
                "compiling the ES iteration (%s members x %s episodes x %s env steps; a program "
                "compiled once is loaded from the compilation cache afterwards)",
                config.es.population_size,
                config.es.n_episodes,
                self.parts.env.episode_length,
            )
            start = time.perf_counter()
            call = jax.jit(make_train_call(self.parts, count), out_shardings=self.parts.replicated)
            self.programs[count] = lower_afresh(call, state).compile()
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
    metrics = distributed.to_host(metrics)
    run_s = time.perf_counter() - tick
    return new_state, metric_rows(parts, done, metrics, run_s, calls.seconds)


def ties_stop_the_step(es: ESConfig) -> bool:
    """Whether a population whose members all return the same moves the centre by nothing but
    weight decay: OpenES whose shaping subtracts a baseline (ranks, z-scores), or whose
    antithetic pairs cancel (the identity)."""
    return es.strategy == OPEN_ES and (es.shaping != "identity" or es.antithetic)


@dataclasses.dataclass
class Reporter:
    """Where each iteration's metrics row goes: the run's ``history``, its metrics files
    (``writer``, the primary process only), ``progress_fn`` and the progress ``bar``."""

    history: list[dict[str, Any]]
    writer: MetricsWriter | None
    bar: Any
    progress_fn: Callable[[dict[str, Any]], None] | None
    started: float
    warn_ties: bool = False  # whether a population tied throughout is still to be reported

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
            MetricsWriter(run_dir, start, config.run.tensorboard, columns=columns)
            if run_dir is not None and primary
            else None
        )
        history = list(writer.kept) if writer else (read_history(run_dir, start) if run_dir else [])
        bar = None
        if progress and primary:
            from tqdm.auto import tqdm

            bar = tqdm(total=config.run.iterations, initial=start, desc="ES", unit="it")
        return cls(history, writer, bar, progress_fn, started, warn_ties=ties_stop_the_step(config.es))

    def write(self, rows: list[dict[str, Any]]) -> None:
        """Stamps each row with the run's wall time and hands it to every destination."""
        for row in rows:
            row["wall_s"] = time.perf_counter() - self.started
            self.history.append(row)
            if self.writer:
                self.writer.write(row)
            if self.progress_fn is not None:
                self.progress_fn(row)
            if self.warn_ties and row["nan_episodes"] == 0 and row["return_max"] == row["return_min"]:
                logger.warning(
                    "iteration %d: every member returned %g, so the ES step is zero and only weight "
                    "decay moves the centre (a sparse reward that no member reaches gives no signal); "
                    "logged once per run",
                    row["iteration"],
                    row["return_max"],
                )
                self.warn_ties = False

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


def past_time_limit(run: RunConfig, started: float) -> bool:
    """Whether ``run.max_minutes`` (0: none) have passed since ``started`` (compile included)."""
    return bool(run.max_minutes) and time.perf_counter() - started > 60 * run.max_minutes


def checkpoint_due(run: RunConfig, done: int, out_of_time: bool) -> bool:
    """Whether to save a checkpoint after ``done`` iterations: at the end of the run (all
    iterations, or the time limit) and every ``run.checkpoint_every`` iterations."""
    return done == run.iterations or out_of_time or bool(run.checkpoint_every and done % run.checkpoint_every == 0)
