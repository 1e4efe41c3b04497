"""Beyond the paper (issue 24): the hierarchical quadruped in the gates corridor seen through
depth, a procedural stand-in for the paper's Figure 9 (whose Gibson scans cannot be shipped),
an IAP high level over depth patches against the blind control.

Each policy's preset (``quadruped-gates-iap``, ``-blind``: Figure 11's hierarchy, ES and budget)
trains on ``seeds`` seeds, each in its own run directory ``<out>/<preset>-seed<k>`` (resumed
from its checkpoint, skipped once finished). A finished run's final centre is evaluated on
``episodes`` corridors not seen in training (gates and clutter drawn per episode from keys of
:data:`iap_mjx.configs.training.EVAL_SEED`, which no training run uses), recording the
corridor's statistics (``QuadrupedGates.episode_metrics``: gates passed, control steps touching
a gate or clutter, left the corridor, fell over, distance); IAP's also with its eyes closed on
the same corridors (:mod:`iap_mjx.paper.courses`). The corridors are paired, so the per-corridor
difference of gates passed, eyes open minus closed, and its standard error say what the eyes
give a run already with one seed.

The strip (Figure 10's drawing, :func:`iap_mjx.paper.fig10.draw_strip`): one episode of IAP
seed 0's final centre on an unseen corridor, frames evenly spaced over it, the depth camera
inset with the selected patches in red. It is drawn once per checkpoint (``gates-strip.json``
keeps the step it shows and the episode's return).

Writes ``gates.json``, ``gates.png`` and the strip in ``out`` and returns the markdown table.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from iap_mjx import configs
from iap_mjx.checks import require_int
from iap_mjx.configs.training import EVAL_SEED
from iap_mjx.envs.quadruped_gates import QuadrupedGates
from iap_mjx.files import write_json
from iap_mjx.paper import courses
from iap_mjx.sections import mean_std, reproduce_command, tracked_copy, write_results_section

logger = logging.getLogger(__name__)

POLICIES = {"IAP": "quadruped-gates-iap", "blind": "quadruped-gates-blind"}
"""The policies (labels) and their presets."""
SEEING = ("IAP",)  # the policies evaluated with their eyes closed
STATISTICS = QuadrupedGates.episode_metrics  # gates_passed, collisions, left_corridor, fell_over, distance
SECTION = "gates"  # the RESULTS.md section and experiments/ folder
STRIP = "gates-strip"  # the strip's PNG and JSON in the output folder


def check(overrides: tuple[str, ...]) -> dict[str, configs.TrainConfig]:
    """Every policy's config, validated (env settings included) before anything compiles."""
    return courses.check(SECTION, POLICIES, overrides)


def reproduce_gates(
    out_dir: str | Path,
    *,
    seeds: int = 1,
    overrides: tuple[str, ...] = (),
    episodes: int = 20,
    frames: int = 6,
    train: bool = True,
    results: str | Path | None = None,
    export: str | Path | None = None,
) -> str:
    """Trains (``train=False``: only reads) both policies on ``seeds`` seeds, seed by seed,
    evaluates the finished runs on ``episodes`` unseen corridors each, draws the strip of IAP
    seed 0 once it is finished (``frames`` frames), writes ``gates.json`` / ``gates.png`` in
    ``out_dir`` and returns the markdown table; ``results``: a markdown file (RESULTS.md) whose
    ``gates`` section is rewritten with it, its figures copied to ``experiments/gates/``;
    ``export``: a folder (e.g. ``pretrained/quadruped-gates``) that receives each run's newest
    checkpoint, config and metrics as ``<preset>-seed<k>``, finished or not."""
    require_int("episodes", episodes)
    require_int("seeds", seeds)
    require_int("frames", frames)
    checked = check(tuple(overrides))
    out_dir = Path(out_dir)
    rows, summaries = courses.report(
        "gates",
        checked,
        POLICIES,
        SEEING,
        STATISTICS,
        out_dir,
        seeds=seeds,
        train=train,
        episodes=episodes,
        export=None if export is None else Path(export),
    )
    png = courses.plot(
        rows,
        summaries,
        out_dir / "gates.png",
        title=f"quadruped-gates from depth: IAP and blind, {summaries['IAP']['parameters']:,} parameters each",
        statistic="gates_passed",
        what="gates passed",
        colours=("tab:blue", "tab:gray"),
    )
    strip = draw_strip(out_dir, rows, frames=frames)
    markdown = table(rows, summaries, seeds=seeds)
    if results is not None:
        write_results(
            Path(results),
            markdown,
            png,
            strip,
            seeds=seeds,
            overrides=tuple(overrides),
            episodes=episodes,
            frames=frames,
        )
    return markdown


def draw_strip(out_dir: Path, rows: list[dict[str, Any]], *, frames: int) -> tuple[Path, dict[str, Any]] | None:
    """IAP seed 0's strip, ``<out_dir>/gates-strip.png``, and ``{"run_dir", "step", "return",
    "frames"}`` (kept in ``gates-strip.json``); drawn again only when the run's latest checkpoint
    or ``frames`` changed. ``None`` until that run has finished."""
    from iap_mjx.es import checkpoint
    from iap_mjx.paper import fig10

    if not any(row["policy"] == "IAP" and row["seed"] == 0 and row["finished"] for row in rows):
        return None
    run_dir = out_dir / f"{POLICIES['IAP']}-seed0"
    step = checkpoint.latest_step(run_dir)
    png, record = out_dir / f"{STRIP}.png", out_dir / f"{STRIP}.json"
    drawn = json.loads(record.read_text()) if record.exists() else None
    if png.exists() and drawn is not None and drawn["step"] == step and drawn["frames"] == frames:
        return png, drawn
    ((_, env, policy),) = fig10.check((run_dir,)).values()
    path, episode_return = fig10.draw_strip(run_dir, env, policy, png, frames=frames)
    drawn = {"run_dir": str(run_dir), "step": step, "return": float(episode_return), "frames": frames}
    write_json(record, drawn)
    logger.info("gates: %s, return %.2f", path, episode_return)
    return path, drawn


def paired_lines(rows: list[dict[str, Any]]) -> list[str]:
    """Per finished seeing run: gates passed per corridor with its eyes open minus closed on
    the same corridors, the mean difference, its standard error (the sample std over
    sqrt(corridors)) and their ratio; one markdown list item each."""
    lines = []
    for row in rows:
        if row["policy"] in SEEING and row["finished"]:
            d = np.asarray(row["course"]["gates_passed"]) - np.asarray(row["eyes_closed"]["gates_passed"])
            se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0
            ratio = f"{np.mean(d) / se:+.1f} SE" if se > 0 else "no spread"
            lines.append(
                f"- {row['policy']} seed {row['seed']}: gates passed per corridor, eyes open minus closed on the "
                f"same {len(d)} corridors: {np.mean(d):+.2f} (SE {se:.2f}; {ratio})."
            )
    return lines


def table(rows: list[dict[str, Any]], summaries: dict[str, dict[str, Any]], *, seeds: int) -> str:
    """Markdown: per policy its parameters, final return, gates passed, gate or clutter contact
    steps, the shares that left the corridor and fell over, and distance per episode (each the
    mean ± std over finished seeds of the per-seed means over the evaluation corridors), how far
    the runs got; then the eyes-closed table and the paired differences."""
    lines = [
        "| policy | parameters | final return | gates passed per episode | gate or clutter contact steps per "
        "episode | left the corridor (share) | fell over (share) | distance (m) | seeds finished | iterations | "
        "env steps per run |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for label, summary in summaries.items():
        lines.append(
            f"| {label} (`{POLICIES[label]}`) | {summary['parameters']:,} | {mean_std(summary['return'])} | "
            f"{mean_std(summary['gates_passed'], 2)} | {mean_std(summary['collisions'])} | "
            f"{mean_std(summary['left_corridor'], 2)} | {mean_std(summary['fell_over'], 2)} | "
            f"{mean_std(summary['distance'], 2)} | {summary['finished']} of {seeds} | {summary['iterations']} | "
            f"{summary['env_steps']:,} |"
        )
    eyes_closed = courses.eyes_closed_table(summaries, SEEING, "gates_passed", "gates passed")
    return "\n".join([*lines, "", *eyes_closed, *paired_lines(rows)])


def write_results(
    path: Path,
    markdown: str,
    png: Path,
    strip: tuple[Path, dict[str, Any]] | None,
    *,
    seeds: int,
    overrides: tuple[str, ...],
    episodes: int,
    frames: int,
) -> None:
    """Section ``gates`` of ``path``: the command, the figure, the table and the strip."""
    options = [*overrides, f"--seeds {seeds}", f"--episodes {episodes}", f"--frames {frames}"]
    command = reproduce_command(SECTION, options, out=png.parent, results=path)
    if strip is None:
        shown = "The strip: drawn once IAP seed 0 has finished."
    else:
        strip_png, drawn = strip
        shown = (
            f"The strip: IAP seed 0's checkpoint {drawn['step']} on an unseen corridor (`iap-mjx video --seed "
            f"{EVAL_SEED}`'s episode), return {drawn['return']:.2f}; {drawn['frames']} frames evenly spaced over "
            "it, each the corridor from the camera that follows the robot, the depth camera inset with the "
            "selected patches in red (the high level's choice were it asked at that step).\n\n"
            f"![{STRIP}]({tracked_copy(strip_png, path, SECTION)})"
        )
    body = (
        "## Beyond the paper: the gates corridor seen through depth, IAP against the blind control\n\n"
        f"Command: `{command}`. Curves: the centre's evaluation return at each ES iteration's start, mean and "
        f"std over seeds. Table: each finished run's final centre on {episodes} corridors not seen in training "
        f"(gates and clutter drawn per episode from keys of seed {EVAL_SEED}); per policy the mean ± std over "
        f"seeds of the per-seed means.\n\n![{SECTION}]({tracked_copy(png, path, SECTION)})\n\n{markdown}\n\n{shown}\n"
    )
    write_results_section(path, SECTION, body)
