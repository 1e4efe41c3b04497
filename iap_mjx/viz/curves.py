"""Reward curves of a training run, from its history (the rows of ``metrics.jsonl``:
``TrainResult.history`` or ``iap_mjx.es.metrics_log.read_history``)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Iterable

logger = logging.getLogger(__name__)


def plot_reward_curve(history: Iterable[dict[str, Any]], path: str | Path, *, title: str = "") -> Path:
    """Population mean/min/max return and the centre's evaluation return per iteration -> PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(history)
    iterations = [row["iteration"] for row in rows]
    fig, ax = plt.subplots(figsize=(7, 4))
    if rows and "return_mean" in rows[0]:
        ax.plot(iterations, [row["return_mean"] for row in rows], label="population mean")
        ax.fill_between(iterations, [row["return_min"] for row in rows],
                        [row["return_max"] for row in rows], alpha=0.2, label="population min-max")
    evaluated = [row for row in rows if "eval_return" in row]
    if evaluated:
        ax.plot([row["iteration"] for row in evaluated], [row["eval_return"] for row in evaluated],
                "o-", color="black", markersize=3, label="centre (evaluation seeds)")
    ax.set_xlabel("ES iteration")
    ax.set_ylabel("episode return")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    logger.info("wrote %s", path)
    return path
