"""Reproducing the paper's Figures 1 and 6: inference time per forward pass next to return.

For each attention variant of Cheetah-Run from 100x100 RGB (``cheetah-run-pixels`` and its
kernel variants), it times one policy forward pass (one observation, as the paper's bars:
the mean of 100 passes after compilation) and trains the preset for the same number of ES
iterations on several seeds, reporting the mean and std of the final evaluation return.

- ``fig6``: ReLU, hybrid (3,2), (6,3), (10,5), (16,8) and Brute.
- ``fig1``: IAP (hybrid (10,5)) and Brute (Tang et al.'s AttentionAgent).

Writes ``<out>/<figure>.png``, ``<out>/<figure>.json`` and returns a markdown table.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from iap_mjx import configs
from iap_mjx.checks import require_int
from iap_mjx.files import write_json
from iap_mjx.paper.report_runs import check_evaluated, check_seed_not_set, trained_curve
from iap_mjx.paper.timing import inference_seconds

logger = logging.getLogger(__name__)

VARIANTS = {
    "fig6": [
        ("ReLU", "cheetah-run-pixels-relu"),
        ("(3,2)", "cheetah-run-pixels-hybrid-3-2"),
        ("(6,3)", "cheetah-run-pixels-hybrid-6-3"),
        ("(10,5)", "cheetah-run-pixels"),
        ("(16,8)", "cheetah-run-pixels-hybrid-16-8"),
        ("Brute", "cheetah-run-pixels-brute"),
    ],
    "fig1": [("IAP", "cheetah-run-pixels"), ("Brute Force", "cheetah-run-pixels-brute")],
}


def check(figure: str, overrides: tuple[str, ...]) -> list[tuple[str, configs.TrainConfig, str]]:
    """``figure``'s variants as ``(label, config, preset)``, every config and env validated
    before anything compiles."""
    if figure not in VARIANTS:
        raise ValueError(f"unknown figure {figure!r}; valid: {', '.join(VARIANTS)}")
    from iap_mjx import envs

    check_seed_not_set(figure, overrides)
    variants = [
        (label, configs.apply_overrides(configs.get(preset), overrides), preset) for label, preset in VARIANTS[figure]
    ]
    for _, config, _ in variants:
        envs.check_spec(config.env)
    check_evaluated(figure, (config for _, config, _ in variants))
    return variants


def reproduce_fig1_fig6(
    figure: str,
    out_dir: str | Path,
    *,
    seeds: int = 3,
    overrides: tuple[str, ...] = (),
    passes: int = 100,
    train: bool = True,
) -> str:
    """Runs ``figure`` (``fig1`` or ``fig6``); writes PNG and JSON; returns a markdown table.

    Each (preset, seed) trains in ``<out_dir>/<preset>-seed<seed>``: a killed run resumes
    there, and ``fig1`` reuses the Brute and (10,5) runs of a ``fig6`` in the same ``out_dir``.
    ``train=False`` trains nothing and reports the runs already there, however far they got
    (the table's seeds and iterations columns say how far).
    """
    require_int("seeds", seeds)
    require_int("passes", passes)
    variants = check(figure, tuple(overrides))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    for label, config, preset in variants:
        runs = [trained_curve(config, seed, out_dir / f"{preset}-seed{seed}", train=train) for seed in range(seeds)]
        trained = [run for run in runs if run is not None]
        if not trained:
            logger.info("%s: no runs in %s yet", label, out_dir)
            continue
        curves = [curve for curve, _ in trained]
        length = min(len(curve) for curve in curves)  # seeds compared at the same iteration
        seconds = inference_seconds(config, passes=passes)
        rows.append(
            {
                "variant": label,
                "preset": preset,
                "inference_s": seconds,
                "returns": [curve[length - 1] for curve in curves],
                "curves": curves,
                "train_wall_s": sum(s for _, s in trained),
                "iterations": length,
            }
        )
        rows[-1]["complete"] = len(curves) == seeds and rows[-1]["iterations"] == config.run.iterations
        logger.info("%s: %.4f s per forward pass, returns %s", label, seconds, rows[-1]["returns"])
    if not rows:
        raise ValueError(f"no runs of {figure} in {out_dir} to report")
    complete = len(rows) == len(variants) and all(row["complete"] for row in rows)
    write_json(out_dir / f"{figure}.json", rows, indent=2)
    plot(
        rows,
        out_dir / f"{figure}.png",
        title=f"{figure}: Cheetah-Run from 100x100 RGB" + ("" if complete else " (in progress)"),
    )
    return table(rows)


def plot(rows: list[dict[str, Any]], path: Path, *, title: str) -> Path:
    """Writes :func:`figure` of ``rows`` to ``path``."""
    from iap_mjx.viz.curves import save_png

    return save_png(figure(rows, title=title), path, dpi=110)


def figure(rows: list[dict[str, Any]], *, title: str):
    """Left, as the paper: bars of inference time per forward pass, crosses with std bars
    of the mean final return. Right: mean evaluation-return curves, shaded +- std over seeds
    (cut to the shortest seed)."""
    from iap_mjx.viz.curves import plot_mean_band, subplots

    labels = [row["variant"] for row in rows]
    x = np.arange(len(rows))
    fig, (ax, curves) = subplots(1, 2, figsize=(1.3 * len(rows) + 8, 4))
    ax.bar(x, [row["inference_s"] for row in rows], color="tab:blue", alpha=0.7)
    ax.set_ylabel("inference time (s)")
    ax.set_xticks(x, labels)
    twin = ax.twinx()
    twin.errorbar(
        x,
        [np.mean(row["returns"]) for row in rows],
        yerr=[np.std(row["returns"]) for row in rows],
        fmt="x",
        color="tab:orange",
        markersize=10,
        capsize=4,
    )
    twin.set_ylabel("reward (mean over seeds)")
    ax.set_title(title)
    for row in rows:
        plot_mean_band(curves, row["curves"], row["variant"])
    curves.set_xlabel("ES iteration (the centre at its start)")
    curves.set_ylabel("evaluation return")
    curves.set_title(f"mean +- std over {len(rows[0]['curves'])} seeds")
    curves.legend(fontsize="small")
    fig.tight_layout()
    return fig


def table(rows: list[dict[str, Any]]) -> str:
    """A markdown table of the rows."""
    from iap_mjx.sections import mean_std

    lines = [
        "| variant | preset | ms per forward pass | return (mean ± std) | seeds | iterations | training s (all seeds) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        lines.append(
            f"| {row['variant']} | `{row['preset']}` | {1e3 * row['inference_s']:.3f} | "
            f"{mean_std(row['returns'])} | {len(row['returns'])} | "
            f"{row['iterations']} | {row['train_wall_s']:.0f} |"
        )
    return "\n".join(lines)
