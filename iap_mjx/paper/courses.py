"""The quadruped's course reports (Figure 11 on the walls, the gates corridor beyond the paper):
a hierarchical policy's run as a row with its evaluation on courses not seen in training, eyes
open and (for a policy that sees) closed; per-policy summaries over seeds; the eyes-closed table
and the figure of curves and obstacles passed.

A course env keeps per-episode statistics (``episode_metrics``, e.g. ``walls_passed``); the
evaluation stores them beside the return in the run directory
(:func:`iap_mjx.paper.evaluations.evaluate_course`). With its eyes closed the same checkpoint
runs on the same courses with its high level given a zeroed image (``policy.blind=true``, as
the blind control sees it): what it loses then is what its eyes give it, per seed, without the
seed-to-seed spread that a comparison with the blind control carries.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from iap_mjx import configs
from iap_mjx.files import write_json
from iap_mjx.paper.evaluations import evaluate_course, seed_means
from iap_mjx.paper.report_runs import built_policies, check_evaluated, check_seed_not_set, reported_run
from iap_mjx.sections import mean_std


def check(report: str, presets: dict[str, str], overrides: tuple[str, ...]) -> dict[str, configs.TrainConfig]:
    """``{label: config}``: each of ``presets`` (``{label: preset}``) with ``overrides``,
    validated (env settings included) before anything compiles; ``report`` names the report in
    the errors."""
    from iap_mjx import envs

    check_seed_not_set(report, overrides)
    checked = {}
    for label, preset in presets.items():
        config = configs.apply_overrides(configs.get(preset), overrides)
        envs.check_spec(config.env)
        checked[label] = config
    check_evaluated(report, checked.values())
    return checked


def report(
    name: str,
    checked: dict[str, configs.TrainConfig],
    presets: dict[str, str],
    seeing: tuple[str, ...],
    statistics: tuple[str, ...],
    out_dir: Path,
    *,
    seeds: int,
    train: bool,
    episodes: int,
    export: Path | None,
    courses_of: int | None = None,
) -> tuple[list[dict[str, Any]], dict[str, dict[str, Any]]]:
    """Report ``name``'s runs (:func:`course_rows`) and its per-policy summaries
    (:func:`summaries` of ``statistics``, each policy's parameter count counted from its built
    policy), also written to ``<out_dir>/<name>.json``; ``ValueError`` if no run has anything
    to report yet. ``courses_of``: the iteration whose evaluation courses every finished run
    plays (default: its own checkpoint's)."""
    from iap_mjx import policies

    parameters = {label: policies.init_param_count(policy) for label, policy in built_policies(checked).items()}
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = course_rows(
        checked,
        presets,
        seeing,
        out_dir,
        seeds=seeds,
        train=train,
        episodes=episodes,
        export=export,
        courses_of=courses_of,
    )
    if not rows:
        raise ValueError(f"no {name} runs in {out_dir} to report")
    summarised = summaries(rows, parameters, statistics)
    write_json(out_dir / f"{name}.json", {"parameters": parameters, "summaries": summarised, "rows": rows})
    return rows, summarised


def _course_row(
    label: str,
    preset: str,
    config: configs.TrainConfig,
    seed: int,
    out_dir: Path,
    *,
    seeing: bool,
    train: bool,
    episodes: int,
    export: Path | None = None,
    courses_of: int | None = None,
) -> dict[str, Any] | None:
    """Policy ``label``'s run of ``config`` (``preset`` with the report's overrides) with
    ``seed`` in ``out_dir/<preset>-seed<k>``: its curve, env steps, seconds and (finished) its
    evaluation on ``episodes`` fresh courses (``"course"``), with ``seeing`` also with its eyes
    closed (``"eyes_closed"``), on iteration ``courses_of``'s courses if given; with ``export``,
    its newest checkpoint and files are copied to ``export/<preset>-seed<k>``. ``None`` while
    the run has no iteration to report."""
    name = f"{preset}-seed{seed}"

    def evaluate(run_dir: Path, step: int) -> dict[str, Any]:
        courses = {"course": evaluate_course(run_dir, step, episodes=episodes, courses_of=courses_of)}
        if seeing:
            courses["eyes_closed"] = evaluate_course(
                run_dir, step, episodes=episodes, eyes_closed=True, courses_of=courses_of
            )
        return courses

    reported = reported_run(
        config, seed, out_dir / name, train=train, evaluate=evaluate, export=None if export is None else export / name
    )
    return None if reported is None else {"policy": label, "preset": preset, **reported[0]}


def course_rows(
    checked: dict[str, configs.TrainConfig],
    presets: dict[str, str],
    seeing: tuple[str, ...],
    out_dir: Path,
    *,
    seeds: int,
    train: bool,
    episodes: int,
    export: Path | None,
    courses_of: int | None = None,
) -> list[dict[str, Any]]:
    """:func:`_course_row` of every policy (``checked``: :func:`check`'s) on seeds
    ``0..seeds-1``, seed by seed so that the policies compare early; the runs with nothing to
    report yet are left out."""
    rows = []
    for seed in range(seeds):
        for label, config in checked.items():
            row = _course_row(
                label,
                presets[label],
                config,
                seed,
                out_dir,
                seeing=label in seeing,
                train=train,
                episodes=episodes,
                export=export,
                courses_of=courses_of,
            )
            if row is not None:
                rows.append(row)
    return rows


def summaries(
    rows: list[dict[str, Any]], parameters: dict[str, int], statistics: tuple[str, ...]
) -> dict[str, dict[str, Any]]:
    """:func:`summarise` of each policy of ``parameters`` (``{label: parameter count}``)."""
    return {
        label: summarise([row for row in rows if row["policy"] == label], count, statistics)
        for label, count in parameters.items()
    }


def summarise(rows: list[dict[str, Any]], parameters: int, statistics: tuple[str, ...]) -> dict[str, Any]:
    """One policy's runs: its parameters, the per-seed means of the finished runs' evaluation
    episodes (``"return"`` and each of ``statistics``: lists over finished seeds; a seeing
    policy's also with its eyes closed, ``"eyes_closed"``, the same seeds in the same order),
    how many finished, and the furthest run's iterations and env steps."""
    done = [row for row in rows if row["finished"]]
    names = ("return", *statistics)
    summary = {
        "parameters": parameters,
        "finished": len(done),
        "iterations": max((row["iterations"] for row in rows), default=0),
        "env_steps": max((row["env_steps"] for row in rows), default=0),
        **seed_means(rows, "course", names),
    }
    if all("eyes_closed" in row for row in done):
        summary["eyes_closed"] = seed_means(rows, "eyes_closed", names)
    return summary


def eyes_closed_table(
    summaries: dict[str, dict[str, Any]], seeing: tuple[str, ...], statistic: str, what: str
) -> list[str]:
    """Markdown lines (ending in a blank one; none before a seeing run has finished): each of
    the ``seeing`` policies' final return and ``statistic`` (``what``, e.g. "walls passed")
    with its eyes open and closed on the same courses, mean ± std over its finished seeds, and
    per seed what closing them changes."""
    finished = [label for label in seeing if summaries[label]["finished"]]
    if not finished:
        return []
    lines = [
        "With their eyes closed: the same final checkpoints on the same courses, the high level given a zeroed "
        "image (the condition `policy.blind=true`, as the blind control sees it):",
        "",
        f"| policy | final return, eyes open | eyes closed | {what} per episode, eyes open | eyes closed | "
        f"{what}, open minus closed, per seed |",
        "|---|---:|---:|---:|---:|---|",
    ]
    for label in finished:
        summary, closed = summaries[label], summaries[label]["eyes_closed"]
        gains = ", ".join(f"{open_ - shut:+.2f}" for open_, shut in zip(summary[statistic], closed[statistic]))
        lines.append(
            f"| {label} | {mean_std(summary['return'])} | {mean_std(closed['return'])} | "
            f"{mean_std(summary[statistic], 2)} | {mean_std(closed[statistic], 2)} | {gains} |"
        )
    return [*lines, ""]


def plot(
    rows: list[dict[str, Any]],
    summaries: dict[str, dict[str, Any]],
    path: Path,
    *,
    title: str,
    statistic: str,
    what: str,
    colours: tuple[str, ...],
) -> Path:
    """Left: each policy's evaluation return per ES iteration, mean and band over its seeds,
    the parameter counts in the legend (``title`` above). Right: ``statistic`` (``what``, e.g.
    "walls passed") per episode on fresh courses, mean ± std over finished seeds, a bar per
    policy in ``colours``."""
    from iap_mjx.viz.curves import plot_mean_band, save_png, subplots

    fig, (curves, bars) = subplots(1, 2, figsize=(11, 4), gridspec_kw={"width_ratios": (2, 1)})
    for label, summary in summaries.items():
        runs = [row["curve"] for row in rows if row["policy"] == label]
        if runs:
            plot_mean_band(curves, runs, f"{label} ({summary['parameters']:,} parameters, {len(runs)} seeds)")
    curves.set_xlabel("ES iteration (the centre at its start)")
    curves.set_ylabel("evaluation return (m along the course)")
    curves.set_title(title)
    curves.legend(fontsize="small")
    labels = list(summaries)
    values = [summaries[label][statistic] for label in labels]
    bars.bar(
        labels,
        [np.mean(v) if v else 0.0 for v in values],
        yerr=[np.std(v) if v else 0.0 for v in values],
        capsize=4,
        color=list(colours),
    )
    bars.set_ylabel(f"{what} per episode (fresh courses)")
    bars.set_title("finished runs, mean ± std over seeds")
    return save_png(fig, path)
