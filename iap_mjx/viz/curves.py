"""Reward curves of a training run, from its history (the rows of ``metrics.jsonl``:
``TrainResult.history`` or ``iap_mjx.es.metrics_log.read_history``), and of several seeds'
runs as a mean with a band."""

from __future__ import annotations

import logging
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

logger = logging.getLogger(__name__)


def subplots(*args: Any, **kwargs: Any) -> tuple[Any, Any]:
    """``matplotlib.pyplot.subplots`` on the Agg backend: every figure goes to a file, and no
    screen is needed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(*args, **kwargs)


def save_png(fig: Any, path: str | Path, *, dpi: int = 100) -> Path:
    """Lays ``fig`` out tightly, writes it to ``path`` and closes it; returns ``path``."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def plot_reward_curve(history: Iterable[dict[str, Any]], path: str | Path, *, title: str = "") -> Path:
    """Population mean/min/max return and the centre's evaluation return per iteration -> PNG."""
    rows = list(history)
    iterations = [row["iteration"] for row in rows]
    fig, ax = subplots(figsize=(7, 4))
    if rows and "return_mean" in rows[0]:
        ax.plot(iterations, [row["return_mean"] for row in rows], label="population mean")
        ax.fill_between(
            iterations,
            [row["return_min"] for row in rows],
            [row["return_max"] for row in rows],
            alpha=0.2,
            label="population min-max",
        )
    evaluated = [row for row in rows if "eval_return" in row]
    if evaluated:
        ax.plot(
            [row["iteration"] for row in evaluated],
            [row["eval_return"] for row in evaluated],
            "o-",
            color="black",
            markersize=3,
            label="centre (evaluation seeds)",
        )
    ax.set_xlabel("ES iteration")
    ax.set_ylabel("episode return")
    ax.set_title(title)
    ax.legend(fontsize=8)
    path = save_png(fig, path, dpi=110)
    logger.info("wrote %s", path)
    return path


def plot_mean_band(ax: Any, curves: list[list[float]], label: str) -> None:
    """Draws on matplotlib ``ax`` the mean of ``curves`` (one per seed: the value at ES
    iterations ``1..T``, cut to the shortest seed's ``T``) shaded +- their std."""
    length = min(len(curve) for curve in curves)
    stacked = np.array([curve[:length] for curve in curves])
    steps = np.arange(1, length + 1)
    mean, std = stacked.mean(0), stacked.std(0)
    ax.plot(steps, mean, label=label)
    ax.fill_between(steps, mean - std, mean + std, alpha=0.2)
