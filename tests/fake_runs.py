"""Hand-written run directories for the reproduce commands' tests: metrics rows and a
checkpoint of ``config``, as training leaves them, in milliseconds instead of compiles."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from iap_mjx.es import checkpoint
from iap_mjx.es.metrics_log import MetricsWriter


def fake_run(
    run_dir: Path, config, iterations: int, returns: list[float], population_max: list[float] | None = None
) -> None:
    """Iterations ``1..iterations`` with evaluation returns ``returns[i - 1]`` (and the
    population's best ``population_max[i - 1]``, default the same), 2 s each after a 30 s
    compile, 1000 env steps per iteration; then checkpoint ``iterations``."""
    writer = MetricsWriter(run_dir, 0, tensorboard=False)
    best = returns if population_max is None else population_max
    for i in range(1, iterations + 1):
        writer.write(
            {
                "iteration": i,
                "eval_return": returns[i - 1],
                "return_max": best[i - 1],
                "run_s": 2.0,
                "compile_s": 30.0,
                "env_steps": i * 1000,
            }
        )
    checkpoint.save(run_dir, iterations, {"x": np.zeros(2)}, config.to_dict())
