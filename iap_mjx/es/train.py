"""``train(config) -> TrainResult``: the whole ES iteration compiled, host work in between.

``train`` builds the run's pieces (:mod:`iap_mjx.es.components`), starts from the state before
iteration 0 or resumes from ``run_dir``'s latest checkpoint, then calls the compiled training
call (``run.iterations_per_call`` fused iterations, :mod:`iap_mjx.es.iteration`) until
``run.iterations`` are done or ``run.max_minutes`` have passed. Between calls the host logs
metrics, writes checkpoints and moves the progress bar (:mod:`iap_mjx.es.bookkeeping`); the
result is packed by :mod:`iap_mjx.es.results`, which also loads and evaluates finished runs.
Every random draw descends from ``run.seed`` through ``fold_in(key, iteration)``, so a resumed
run continues bit for bit.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax

from iap_mjx.configs.training import TrainConfig
from iap_mjx.es import checkpoint
from iap_mjx.es.bookkeeping import (
    CompiledCalls,
    Reporter,
    checkpoint_due,
    past_time_limit,
    start_state,
    training_call_with_timing,
)
from iap_mjx.es.components import build, describe_parameters
from iap_mjx.es.results import TrainResult, result_from_state
from iap_mjx.policies.base import Policy

if TYPE_CHECKING:  # iap_mjx.envs is imported only where an env is built
    from iap_mjx.envs.base import Env

logger = logging.getLogger(__name__)


def train(
    config: TrainConfig,
    *,
    run_dir: str | Path | None = None,
    progress: bool = True,
    env: Env | None = None,
    policy: Policy | None = None,
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

    Returns a :class:`~iap_mjx.es.results.TrainResult`. ``KeyboardInterrupt`` saves a checkpoint
    of the last finished iteration (when ``run_dir`` is set) and is re-raised.
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
    # the class trained, whether the config built it or the caller passed one (the CLI passes
    # the config's, a notebook may pass its own)
    logger.info("policy %s: %s", type(parts.policy).__name__, describe_parameters(parts))
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
