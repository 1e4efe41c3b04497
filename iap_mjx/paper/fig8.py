"""Reproducing the paper's Figure 8: training curves against wall-clock time for brute-force
softmax attention, IAP with ReLU features and IAP hybrid (10, 5), on ``dcs-cartpole-swingup``.

Brute force at the suite's ``L = 19,200`` (2x2 patches) needs an ``L x L`` matrix per frame,
seconds per frame: it cannot train at this machine's scale. So the three methods train at
patch size 8 (``L = 1,200``), where brute force fits, and ReLU and hybrid also at patch size
2. One seed each, a budget in iterations (``run.iterations=...``), each in
``<out>/fig8-<kernel>-p<p>-seed0`` (resumed, skipped once finished).

Wall-clock is honest on a shared machine by construction: the curves' x axis is the
iteration count times each method's steady-state seconds per iteration (plus its compile
time, with the persistent compilation cache off), measured by :func:`measure` with every
method timed in the same process, one after another, on a machine left alone (``timings.json``;
the command says so and measures once, before any training, when the file is missing). Brute force at ``L = 19,200`` is not trained:
its cost per iteration is projected from the same run's timings, the hybrid ``p = 2``
iteration plus the frames of an iteration times the difference of the two methods' measured
time per forward pass.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from iap_mjx import configs, runtime
from iap_mjx.checks import require_int
from iap_mjx.files import write_json
from iap_mjx.paper.report_runs import (
    built_policies,
    check_evaluated,
    check_not_swept,
    check_seed_not_set,
    trained_curve,
)
from iap_mjx.paper.timing import inference_seconds

logger = logging.getLogger(__name__)

PRESET = "dcs-cartpole-swingup"
#: ``(kernel, patch size)`` of every trained curve.
VARIANTS = (("brute", 8), ("relu", 8), ("hybrid", 8), ("relu", 2), ("hybrid", 2))
LABELS = {"brute": "brute-force softmax", "relu": "IAP ReLU", "hybrid": "IAP hybrid (10,5)"}
TIMINGS_FILE = "timings.json"


def variant_overrides(kernel: str, patch_size: int) -> tuple[str, ...]:
    return (f"policy.kernel={kernel}", f"policy.patch_size={patch_size}")


def variant_name(kernel: str, patch_size: int) -> str:
    """The variant's key in ``timings.json``; its run directory is ``<variant_name>-seed0``."""
    return f"fig8-{kernel}-p{patch_size}"


def check(overrides: tuple[str, ...]) -> dict[tuple[str, int], configs.TrainConfig]:
    """Every variant's config (and brute force at ``p = 2`` for the projection), validated
    before anything compiles; ``overrides`` may not set what the figure varies."""
    from iap_mjx import envs

    check_seed_not_set("fig8", overrides)
    check_not_swept("fig8", overrides, ("policy.kernel", "policy.patch_size"), "the kernel and patch size per curve")
    result = {}
    for kernel, patch in (*VARIANTS, ("brute", 2)):
        result[kernel, patch] = configs.apply_overrides(
            configs.get(PRESET), (*overrides, *variant_overrides(kernel, patch))
        )
    check_evaluated("fig8", result.values())
    first = next(iter(result.values()))
    envs.check_spec(first.env)
    return result


def frames_per_iteration(config: configs.TrainConfig) -> int:
    """Frames an ES iteration simulates: the population's episodes and the centre's evaluation."""
    from iap_mjx import envs

    length = envs.episode_length(config.env.name, **dict(config.env.overrides))
    return (config.es.population_size * config.es.n_episodes + config.run.eval_episodes) * length


def time_iterations(config: configs.TrainConfig, iterations: int) -> dict[str, float | int]:
    """Trains ``config`` for ``iterations`` in a scratch directory: the median seconds of the
    iterations after the first (steady state) and the first's compile seconds."""
    from iap_mjx.es import train

    config = dataclasses.replace(config, run=dataclasses.replace(config.run, iterations=iterations, checkpoint_every=0))
    with tempfile.TemporaryDirectory() as scratch:
        history = train(config, run_dir=Path(scratch) / "run", progress=False).history
    return {
        "iteration_s": float(np.median([row["run_s"] for row in history[1:]])),
        "compile_s": float(history[0]["compile_s"]),
        "iterations_timed": iterations - 1,
    }


def measure(
    checked: dict[tuple[str, int], configs.TrainConfig], *, iterations: int = 3, passes: int = 3
) -> dict[str, Any]:
    """Every variant's seconds per iteration and compile seconds (each program compiled, none
    loaded from the persistent cache), then brute force's projected cost per iteration at
    ``p = 2`` from the forward passes of brute force and hybrid at ``p = 2``."""
    require_int("iterations", iterations, 2)  # the first one compiles
    timings: dict[str, Any] = {
        "variants": {},
        "machine": f"{platform.machine()}, {platform.node()}",
        "started": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "compile": "persistent compilation cache off",
    }
    with runtime.persistent_cache_off():
        for kernel, patch in VARIANTS:
            logger.info("timing %s at patch size %d (%d iterations)", kernel, patch, iterations)
            timings["variants"][variant_name(kernel, patch)] = time_iterations(checked[kernel, patch], iterations)
    hybrid = checked["hybrid", 2]
    brute_pass = inference_seconds(checked["brute", 2], passes=passes)
    hybrid_pass = inference_seconds(hybrid, passes=max(passes, 20))  # far shorter: more passes to time it
    frames = frames_per_iteration(hybrid)
    hybrid_iteration = timings["variants"][variant_name("hybrid", 2)]["iteration_s"]
    timings["brute_p2"] = {
        "forward_pass_s": brute_pass,
        "hybrid_forward_pass_s": hybrid_pass,
        "frames_per_iteration": frames,
        "projected_iteration_s": hybrid_iteration + frames * (brute_pass - hybrid_pass),
    }
    return timings


def reproduce_fig8(
    out_dir: str | Path,
    *,
    overrides: tuple[str, ...] = (),
    train: bool = True,
    results: str | Path | None = None,
    timing_iterations: int = 3,
) -> str:
    """Measures the timings (once, when ``timings.json`` is missing: ``timing_iterations`` ES
    iterations of each variant), trains every variant (``train=False``: only reads), writes
    ``fig8.json`` / ``fig8.png`` and returns the table; ``results``: a markdown file whose ``fig8``
    section is rewritten with it."""
    require_int("timing_iterations", timing_iterations, 2)  # the first iteration compiles
    checked = check(tuple(overrides))
    patches = {variant: policy.layer.num_patches for variant, policy in built_policies(checked).items()}
    out_dir = Path(out_dir)
    path = out_dir / TIMINGS_FILE
    if not path.exists():
        if not train:
            raise ValueError(f"no {path}: run `iap-mjx reproduce fig8` once with the machine alone to measure it")
        out_dir.mkdir(parents=True, exist_ok=True)
        logger.info("measuring seconds per iteration of every variant (leave the machine alone)")
        write_json(path, measure(checked, iterations=timing_iterations))
    timings = json.loads(path.read_text())
    rows = []
    for kernel, patch in VARIANTS:
        trained = trained_curve(
            checked[kernel, patch], 0, out_dir / f"{variant_name(kernel, patch)}-seed0", train=train
        )
        if trained is None:
            continue
        curve, seconds = trained
        timing = timings["variants"][variant_name(kernel, patch)]
        rows.append(
            {
                "kernel": kernel,
                "patch_size": patch,
                "curve": curve,
                "iterations": len(curve),
                "patches": patches[kernel, patch],
                "run_seconds": seconds,
                **timing,
            }
        )
    if not rows:
        raise ValueError(f"no fig8 runs in {out_dir} to report")
    write_json(out_dir / "fig8.json", {"timings": timings, "rows": rows})
    png = plot(rows, out_dir / "fig8.png")
    markdown = table(rows, timings, brute_patches=patches["brute", 2])
    if results is not None:
        write_results(Path(results), markdown, png, overrides=tuple(overrides), timings=timings)
    return markdown


def wall_seconds(row: dict[str, Any]) -> np.ndarray:
    """The x axis: compile, then one measured steady-state iteration per point."""
    return row["compile_s"] + row["iteration_s"] * np.arange(1, len(row["curve"]) + 1)


def plot(rows: list[dict[str, Any]], path: Path) -> Path:
    """Evaluation return against wall-clock seconds: solid patch size 8, dashed patch size 2."""
    from iap_mjx.viz.curves import save_png, subplots

    colours = {"brute": "tab:red", "relu": "tab:green", "hybrid": "tab:blue"}
    fig, ax = subplots(figsize=(7, 4))
    for row in rows:
        ax.plot(
            wall_seconds(row),
            row["curve"],
            color=colours[row["kernel"]],
            linestyle="-" if row["patch_size"] == 8 else "--",
            label=f"{LABELS[row['kernel']]}, p = {row['patch_size']} (L = {row['patches']:,})",
        )
    ax.set_xlabel("wall-clock seconds (iterations x seconds per iteration measured alone)")
    ax.set_ylabel("evaluation return")
    ax.set_title("cartpole-swingup, static medium distractions")
    ax.legend(fontsize="small")
    return save_png(fig, path)


def table(rows: list[dict[str, Any]], timings: dict[str, Any], *, brute_patches: int) -> str:
    """Markdown: per curve its seconds per iteration, compile, final and best return; then
    brute force at ``p = 2`` projected, as a ratio to hybrid's measured iteration."""
    lines = [
        "| method | patch size | L | s / iteration (alone) | compile s | iterations | final eval return | "
        "best eval return | wall-clock at the last point (s) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        lines.append(
            f"| {LABELS[row['kernel']]} | {row['patch_size']} | {row['patches']:,} | {row['iteration_s']:.1f} | "
            f"{row['compile_s']:.0f} | {row['iterations']} | {row['curve'][-1]:.1f} | {max(row['curve']):.1f} | "
            f"{wall_seconds(row)[-1]:.0f} |"
        )
    brute = timings["brute_p2"]
    hybrid = timings["variants"][variant_name("hybrid", 2)]["iteration_s"]
    lines += [
        "",
        f"Brute force at patch size 2 (L = {brute_patches:,}), not trained: one forward pass measured "
        f"{brute['forward_pass_s']:.2f} s against hybrid's {1e3 * brute['hybrid_forward_pass_s']:.2f} ms; "
        f"with {brute['frames_per_iteration']:,} frames per iteration its projected iteration takes "
        f"{brute['projected_iteration_s']:,.0f} s, **{brute['projected_iteration_s'] / hybrid:,.0f}x** "
        f"hybrid's measured {hybrid:.1f} s (same timing run, {timings['started']}).",
    ]
    return "\n".join(lines)


def write_results(path: Path, markdown: str, png: Path, *, overrides: tuple[str, ...], timings: dict[str, Any]) -> None:
    """The ``fig8`` section of ``path``: the command, the figure and the table."""
    from iap_mjx.sections import reproduce_command, tracked_copy, write_results_section

    command_line = reproduce_command("fig8", overrides, out=png.parent, results=path)
    image = tracked_copy(png, path, "fig8")
    # the timings measured alone are the figure's x axis: kept beside it, tracked
    tracked_copy(png.parent / TIMINGS_FILE, path, "fig8")
    body = (
        f"## Figure 8: wall-clock curves of brute force, IAP ReLU and IAP hybrid (cartpole-swingup, static medium)"
        f"\n\nCommand: `{command_line}`. One seed per curve. Seconds per iteration: every method timed in one "
        f"process on {timings['machine']}, {timings['started']}, one after another with the machine alone "
        f"(`{TIMINGS_FILE}`; compile seconds with the {timings['compile']}); "
        f"the training runs' own timings are not used.\n\n![fig8]({image})\n\n{markdown}\n"
    )
    write_results_section(path, "fig8", body)
