"""Reproducing the paper's Table 2: the IAP high level's patch size and stride on the quadruped's
walled course.

``quadruped-walls-iap`` trains with ``policy.patch_size=p policy.stride=s`` for each setting
``(p, s)``, one seed, the same budget (the preset's iterations, or ``overrides`` for all). The
setting the preset has itself (4x4 patches, stride 4) is its own run,
``<out>/quadruped-walls-iap-seed<k>``, shared with Figure 11 (:mod:`iap_mjx.paper.fig11`); every other
trains in ``<out>/table2-p<p>-s<s>-seed<k>``. Runs resume from their checkpoints and are
skipped once finished (:func:`iap_mjx.paper.report_runs.reported_run`).

The table's return is the maximum episode return reached in training, as the paper's: the
largest ``return_max`` of the run's metrics (per iteration, the best population member's
return, its mean over ``es.n_episodes`` episodes: one episode's return at the preset's 1),
maximised over the iterations; beside it the largest ``eval_return`` (the centre's mean over
``run.eval_episodes`` evaluation episodes at an iteration's start). A run that walks the whole
course scores its length, so the maximum saturates there and settings tie (compared at the
table's precision, 0.1 m). So each finished run's final centre is also evaluated on
``episodes`` courses never seen in training (Figure 11's courses,
:func:`iap_mjx.paper.evaluations.evaluate_course`): walls passed and return per course, which tell
the settings apart where the maximum cannot. ``L`` is the number of patches on the course's
24x32 camera. Writes ``<out>/table2.json`` and ``<out>/table2.png`` and returns the markdown
table.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from iap_mjx import configs
from iap_mjx.checks import is_int, require_int
from iap_mjx.files import write_json
from iap_mjx.paper.evaluations import evaluate_course
from iap_mjx.paper.report_runs import (
    built_policies,
    check_evaluated,
    check_not_swept,
    check_seed_not_set,
    reported_run,
    train_command,
)
from iap_mjx.sections import reproduce_command, tracked_copy, write_results_section

logger = logging.getLogger(__name__)

PRESET = "quadruped-walls-iap"
SETTINGS = ((1, 1), (2, 2), (4, 4), (4, 2))
"""(patch size, stride): the paper's one surviving row (1, 1), the most patches, and three of
fewer (ours)."""
LARGEST_LISTED_PATCH = 8  # a bad setting's error lists the valid ones up to this patch size
SWEPT = ("policy.patch_size", "policy.stride")


def setting_overrides(patch_size: int, stride: int) -> tuple[str, ...]:
    return (f"policy.patch_size={patch_size}", f"policy.stride={stride}")


def own_setting(config: configs.TrainConfig) -> tuple[int, int]:
    """The ``(patch size, stride)`` ``config``'s IAP high level has (no stride: the patch size)."""
    from iap_mjx.attention import AttentionConfig

    options = dict(config.policy.options)
    patch_size = options.get("patch_size", AttentionConfig.patch_size)
    return patch_size, options.get("stride") or patch_size


def misfit_reason(patch_size: int, stride: int, height: int, width: int, top_l: int) -> str | None:
    """Why ``(patch_size, stride)`` cannot be the high level's on a ``height`` x ``width``
    camera choosing ``top_l`` patches (``iap_mjx.attention.patches.patch_grid``'s reason, or
    too few patches), or ``None`` when it can."""
    from iap_mjx.attention.patches import patch_grid

    try:
        rows, cols = patch_grid(height, width, patch_size, stride)
    except ValueError as error:
        return str(error)
    return None if rows * cols >= top_l else f"L = {rows * cols} patches, fewer than top_l = {top_l}"


def valid_settings(height: int, width: int, top_l: int) -> list[tuple[int, int]]:
    """Every ``(patch size, stride)`` with ``stride <= patch size <= LARGEST_LISTED_PATCH`` that
    fits a ``height`` x ``width`` camera choosing ``top_l`` patches: what a bad setting's error lists."""
    return [
        (p, s)
        for p in range(1, LARGEST_LISTED_PATCH + 1)
        for s in range(1, p + 1)
        if misfit_reason(p, s, height, width, top_l) is None
    ]


def check(
    settings: tuple[tuple[int, int], ...], overrides: tuple[str, ...], seed: int, episodes: int = 20
) -> dict[tuple[int, int], tuple[configs.TrainConfig, str, tuple[str, ...]]]:
    """``{setting: (config, run name, the setting's overrides)}`` (the preset's own setting: its
    own run, no overrides), every setting validated before anything compiles (``ValueError``
    naming a bad one and the valid settings)."""
    from iap_mjx import envs
    from iap_mjx.attention import AttentionConfig

    require_int("seed", seed, 0)
    require_int("episodes", episodes)
    check_seed_not_set("table2", overrides)
    check_not_swept("table2", overrides, SWEPT, "the patch size and stride per setting")
    given = tuple(tuple(setting) for setting in settings)  # lists from JSON or a command line
    if (
        not given
        or len(set(given)) != len(given)
        or not all(len(setting) == 2 and all(is_int(v) for v in setting) for setting in given)
    ):
        raise ValueError(f"settings = {given!r} must be distinct (patch size, stride) pairs of ints")
    settings = tuple((patch_size, stride) for patch_size, stride in given)
    base = configs.apply_overrides(configs.get(PRESET), overrides)
    camera = envs.check_spec(base.env)
    check_evaluated("table2", [base])
    top_l = dict(base.policy.options).get("top_l", AttentionConfig.top_l)
    for patch_size, stride in settings:
        reason = misfit_reason(patch_size, stride, camera.height, camera.width, top_l)
        if reason is not None:
            valid = valid_settings(camera.height, camera.width, top_l)
            raise ValueError(
                f"table2 setting (patch size {patch_size}, stride {stride}): {reason}. Valid (patch "
                f"size, stride) on the {camera.height}x{camera.width} camera with top_l = {top_l}, "
                f"stride <= patch size <= {LARGEST_LISTED_PATCH}: " + ", ".join(f"({p}, {s})" for p, s in valid)
            )
    checked: dict[tuple[int, int], tuple[configs.TrainConfig, str, tuple[str, ...]]] = {}
    for setting in settings:
        own = setting == own_setting(base)
        extra = () if own else setting_overrides(*setting)
        config = base if own else configs.apply_overrides(base, extra)
        checked[setting] = (config, run_name(None if own else setting, seed), extra)
    return checked


def run_name(setting: tuple[int, int] | None, seed: int) -> str:
    """The run directory's name of a (patch size, stride) setting, ``table2-p<patch>-s<stride>-seed<k>``;
    ``None``: the preset's own setting, whose run is Figure 11's (``quadruped-walls-iap-seed<k>``,
    reused)."""
    return f"{PRESET}-seed{seed}" if setting is None else f"table2-p{setting[0]}-s{setting[1]}-seed{seed}"


def reproduce_table2(
    out_dir: str | Path,
    *,
    settings: tuple[tuple[int, int], ...] = SETTINGS,
    seed: int = 0,
    overrides: tuple[str, ...] = (),
    episodes: int = 20,
    train: bool = True,
    results: str | Path | None = None,
    export: str | Path | None = None,
) -> str:
    """Trains (``train=False``: only reads) every setting on ``seed``, evaluates each finished
    run on ``episodes`` unseen courses, writes ``table2.json`` /
    ``table2.png`` in ``out_dir`` and returns the markdown table; ``results``: a markdown file
    whose ``table2`` section is rewritten with it; ``export``: a folder (e.g.
    ``pretrained/quadruped``, tracked by git) that receives each run's newest checkpoint, config
    and metrics under its run directory's name, finished or not."""
    from iap_mjx import policies

    checked = check(tuple(settings), tuple(overrides), seed, episodes)
    built = built_policies({setting: config for setting, (config, _, _) in checked.items()})
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for setting, (config, name, extra) in checked.items():
        reported = reported_run(
            config,
            seed,
            out_dir / name,
            train=train,
            evaluate=lambda run_dir, step: {"course": evaluate_course(run_dir, step, episodes=episodes)},
            export=None if export is None else Path(export) / name,
        )
        if reported is None:
            logger.info("table2 %s: no run in %s yet", setting, out_dir / name)
            continue
        row, history = reported
        best = [float(entry["return_max"]) for entry in history]
        rows.append(
            {
                "patch_size": setting[0],
                "stride": setting[1],
                "patches": built[setting].layer.num_patches,
                "parameters": policies.init_param_count(built[setting]),
                "run": name,
                "command": train_command(PRESET, (*overrides, *extra), seed, out_dir / name),
                "population_max": best,
                "max_return": max(best),
                "max_eval_return": max(row["curve"]),
                **row,
            }
        )
    if not rows:
        raise ValueError(f"no table2 runs in {out_dir} to report")
    write_json(out_dir / "table2.json", rows)
    png = plot(rows, out_dir / "table2.png")
    markdown = table(rows, settings=len(checked))
    if results is not None:
        write_results(
            Path(results),
            markdown,
            png,
            settings=tuple(checked),
            seed=seed,
            overrides=tuple(overrides),
            episodes=episodes,
        )
    return markdown


def table(rows: list[dict[str, Any]], *, settings: int) -> str:
    """Markdown: per setting its patches, parameters, maximum returns, its final centre on unseen
    courses (finished runs), how far it got and its command; then the best setting, once all are
    finished."""
    lines = [
        "| patch size | stride | patches L | parameters | max episode return (population) | "
        "max centre evaluation return | unseen courses: walls passed | unseen courses: return | "
        "iterations | wall-clock (s) | command |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for row in rows:
        course = row.get("course")
        walls_passed, ret = (
            ("", "")
            if course is None
            else (f"{np.mean(course['walls_passed']):.2f}", f"{np.mean(course['return']):.2f}")
        )
        lines.append(
            f"| {row['patch_size']} | {row['stride']} | {row['patches']:,} | {row['parameters']:,} | "
            f"{row['max_return']:.1f} | {row['max_eval_return']:.1f} | {walls_passed} | {ret} | {row['iterations']}"
            f"{'' if row['finished'] else ' (running)'} | {row['seconds']:.0f} | `{row['command']}` |"
        )
    lines.append("")
    finished = [row for row in rows if row["finished"]]
    if len(finished) < settings:
        lines.append(f"Best setting: not decided yet ({len(finished)} of {settings} settings finished).")
        return "\n".join(lines)
    # compared as shown (one decimal): a run that walks the whole course ends a few cm past its
    # length, and such centimetres tell no setting apart
    shown = {row["run"]: round(row["max_return"], 1) for row in rows}
    top = max(shown.values())
    best = [row for row in rows if shown[row["run"]] == top]
    most = max(rows, key=lambda row: row["patches"])
    walls = max(rows, key=lambda row: np.mean(row["course"]["walls_passed"]))
    settings_named = [f"patch size {row['patch_size']}, stride {row['stride']}" for row in best]
    named = "; ".join(settings_named[:-1]) + (" and " if len(best) > 1 else "") + settings_named[-1]
    lines.append(
        f"Best setting by the paper's metric: {named} (max return {top:.1f}"
        f"{', tied' if len(best) > 1 else ''}); the paper's best had the most patches, here patch size "
        f"{most['patch_size']}, stride {most['stride']} (L = {most['patches']:,}, max return "
        f"{most['max_return']:.1f}). Most walls passed on unseen courses: patch size {walls['patch_size']}, "
        f"stride {walls['stride']} ({np.mean(walls['course']['walls_passed']):.2f} a course, "
        f"{len(walls['course']['walls_passed'])} courses)."
    )
    return "\n".join(lines)


def plot(rows: list[dict[str, Any]], path: Path) -> Path:
    """Each setting's running maximum of the population's best return per ES iteration."""
    from iap_mjx.viz.curves import save_png, subplots

    fig, ax = subplots(figsize=(7, 4))
    for row in rows:
        best = row["population_max"]
        ax.plot(
            np.arange(1, len(best) + 1),
            np.maximum.accumulate(best),
            label=f"patch {row['patch_size']}, stride {row['stride']} (L = {row['patches']:,})",
        )
    ax.set_xlabel("ES iteration")
    ax.set_ylabel("max episode return so far (population)")
    ax.set_title("quadruped-walls-iap: patch size and stride")
    ax.legend(fontsize="small")
    return save_png(fig, path)


def write_results(
    path: Path,
    markdown: str,
    png: Path,
    *,
    settings: tuple[tuple[int, int], ...],
    seed: int,
    overrides: tuple[str, ...],
    episodes: int,
) -> None:
    """The ``table2`` section of ``path``: the command, the table and the curves."""
    options = [
        *overrides,
        "--settings " + ",".join(f"{p}x{s}" for p, s in settings),
        f"--seed {seed}",
        f"--episodes {episodes}",
    ]
    command_line = reproduce_command("table2", options, out=png.parent, results=path)
    body = (
        f"## Table 2: patch size and stride of the quadruped's IAP high level\n\nCommand: `{command_line}`. "
        f"One seed (seed {seed}) per setting, the same budget. Max episode return: the largest `return_max` "
        "of the run's metrics (each iteration's best population member), over the iterations trained; "
        "beside it the largest `eval_return` (the centre's mean over its evaluation episodes); a run that "
        "walks the whole course scores its length, so the population's maximum saturates there. "
        "Unseen courses: each finished "
        f"run's final centre on {episodes} courses never seen in training (Figure 11's), the mean walls "
        "passed and return per course. L: patches on the course's camera."
        f"\n\n![table2]({tracked_copy(png, path, 'table2')})\n\n{markdown}\n"
    )
    write_results_section(path, "table2", body)
