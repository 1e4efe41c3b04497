"""Reproducing the paper's Figure 11: ES curves of the hierarchical quadruped on the walled course
with an IAP, a CNN and a blind high level, their parameter counts, and how many walls each
passes on courses it never saw.

Each policy's preset (``quadruped-walls-iap``, ``-cnn``, ``-blind``: the same ES, budget and low
level) trains on several seeds, each in its own run directory ``<out>/<preset>-seed<k>``
(resumed from its checkpoint, skipped once finished: :func:`iap_mjx.paper.report_runs.reported_run`).
A finished run's final centre is then evaluated on ``episodes`` episodes of the course, each
recording the course statistics the env keeps (``QuadrupedWalls.episode_metrics``: walls
passed, fell off the platform, control steps touching a wall, distance along the course).

The evaluation's courses are unseen in training: the walls (their positions along the course,
sides and gaps) are drawn per episode from the episode's reset key
(``QuadrupedWalls._place_world``), and the evaluation's keys derive from
:data:`iap_mjx.configs.training.EVAL_SEED`, which no training run uses; a course is a draw of
continuous positions, so none of them is, but for probability zero, a course trained on.
Evaluations are stored in the run directory (``eval.json``,
:func:`iap_mjx.paper.evaluations.evaluate_course`), so a report reads them instead of evaluating
again.

The seeing policies (IAP, CNN) are also evaluated with their eyes closed: the same checkpoint on
the same courses, its high level given a zeroed image (``policy.blind=true``, as the blind
control sees it). What a trained policy loses then is what its eyes give it, measured per seed
on the same courses, so the seed-to-seed spread that the comparison with the blind control
carries does not enter it.

Writes ``<out>/fig11.json`` and ``<out>/fig11.png`` and returns the markdown table with the
acceptance bars (:func:`bars`: IAP against the CNN, each seeing policy against the blind one)
stated as lines.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from iap_mjx import configs
from iap_mjx.checks import require_int
from iap_mjx.configs.training import EVAL_SEED
from iap_mjx.envs.quadruped import QuadrupedWalls
from iap_mjx.files import write_json
from iap_mjx.paper.evaluations import evaluate_course, seed_means
from iap_mjx.paper.report_runs import built_policies, check_evaluated, check_seed_not_set, reported_run
from iap_mjx.sections import check_section_name, mean_std, reproduce_command, tracked_copy, write_results_section

logger = logging.getLogger(__name__)

POLICIES = {"IAP": "quadruped-walls-iap", "CNN": "quadruped-walls-cnn", "blind": "quadruped-walls-blind"}
"""Figure 11's policies (labels) and their presets."""
SEEING = ("IAP", "CNN")  # the policies evaluated with their eyes closed
STATISTICS = QuadrupedWalls.episode_metrics  # walls_passed, fell_off, wall_contacts, distance
MIN_PARAMETER_RATIO = 5.0  # the bar: the CNN has at least 5x IAP's parameters
SECTION = "fig11"  # the RESULTS.md section and experiments/ folder written by default


def check(overrides: tuple[str, ...]) -> dict[str, configs.TrainConfig]:
    """Every policy's config, validated (env settings included) before anything compiles."""
    from iap_mjx import envs

    check_seed_not_set("fig11", overrides)
    checked = {}
    for label, preset in POLICIES.items():
        config = configs.apply_overrides(configs.get(preset), overrides)
        envs.check_spec(config.env)
        checked[label] = config
    check_evaluated("fig11", checked.values())
    return checked


def run_row(
    label: str,
    config: configs.TrainConfig,
    seed: int,
    out_dir: Path,
    *,
    train: bool,
    episodes: int,
    export: Path | None = None,
) -> dict[str, Any] | None:
    """One run: its curve, env steps, seconds and (finished) its evaluation on fresh courses, a
    seeing policy's also with its eyes closed (``"eyes_closed"``); with ``export``, its newest
    checkpoint and files are copied to ``export/<preset>-seed<k>``."""
    name = f"{POLICIES[label]}-seed{seed}"

    def evaluate(run_dir: Path, step: int) -> dict[str, Any]:
        courses = {"course": evaluate_course(run_dir, step, episodes=episodes)}
        if label in SEEING:
            courses["eyes_closed"] = evaluate_course(run_dir, step, episodes=episodes, eyes_closed=True)
        return courses

    reported = reported_run(
        config, seed, out_dir / name, train=train, evaluate=evaluate, export=None if export is None else export / name
    )
    return None if reported is None else {"policy": label, "preset": POLICIES[label], **reported[0]}


def reproduce_fig11(
    out_dir: str | Path,
    *,
    seeds: int = 3,
    overrides: tuple[str, ...] = (),
    episodes: int = 20,
    train: bool = True,
    results: str | Path | None = None,
    export: str | Path | None = None,
    section: str = SECTION,
) -> str:
    """Trains (``train=False``: only reads) every policy on ``seeds`` seeds, seed by seed so that
    the policies compare early, evaluates the finished runs on ``episodes`` fresh courses each,
    writes ``fig11.json`` / ``fig11.png`` in ``out_dir`` and returns the markdown table;
    ``results``: a markdown file (RESULTS.md) whose section ``section`` (default ``fig11``; another
    name keeps a second experiment, e.g. from another low level, beside the first) is rewritten
    with it, its figure copied to ``experiments/<section>/``;
    ``export``: a folder (e.g. ``pretrained/quadruped``, tracked by git) that receives each run's
    newest checkpoint, config and metrics as ``<preset>-seed<k>``, finished or not."""
    require_int("episodes", episodes)
    require_int("seeds", seeds)
    check_section_name(section, "fig11-turn")
    from iap_mjx import policies

    checked = check(tuple(overrides))
    parameters = {label: policies.init_param_count(policy) for label, policy in built_policies(checked).items()}
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    export = None if export is None else Path(export)
    rows = [
        row
        for seed in range(seeds)
        for label, config in checked.items()
        if (row := run_row(label, config, seed, out_dir, train=train, episodes=episodes, export=export)) is not None
    ]
    if not rows:
        raise ValueError(f"no fig11 runs in {out_dir} to report")
    summaries = {
        label: summarise([row for row in rows if row["policy"] == label], parameters[label]) for label in POLICIES
    }
    write_json(out_dir / "fig11.json", {"parameters": parameters, "summaries": summaries, "rows": rows})
    png = plot(rows, summaries, out_dir / "fig11.png")
    markdown = table(summaries, seeds=seeds)
    if results is not None:
        write_results(
            Path(results), markdown, png, seeds=seeds, overrides=tuple(overrides), episodes=episodes, section=section
        )
    return markdown


def summarise(rows: list[dict[str, Any]], parameters: int) -> dict[str, Any]:
    """One policy's runs: its parameters, the per-seed means of the finished runs' evaluation
    episodes (``"return"`` and each statistic: lists over finished seeds; a seeing policy's
    also with its eyes closed, ``"eyes_closed"``, the same seeds in the same order), how many
    finished, and the furthest run's iterations and env steps."""
    done = [row for row in rows if row["finished"]]
    names = ("return", *STATISTICS)
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


def bars(summaries: dict[str, dict[str, Any]], *, seeds: int) -> list[str]:
    """The acceptance bars as lines, decided once every seed of every policy is finished."""
    iap, cnn, blind = (summaries[label] for label in POLICIES)
    ratio = cnn["parameters"] / iap["parameters"]
    if any(summary["finished"] < seeds for summary in summaries.values()):
        finished = sum(summary["finished"] for summary in summaries.values())
        return [
            f"Bars: not decided yet ({finished} of {len(POLICIES) * seeds} runs finished). Parameters: CNN "
            f"{cnn['parameters']:,}, IAP {iap['parameters']:,} ({ratio:.1f}x; bar: >= {MIN_PARAMETER_RATIO:.0f}x)."
        ]
    floor = np.mean(cnn["return"]) - np.std(cnn["return"])
    near = np.mean(iap["return"]) >= floor and ratio >= MIN_PARAMETER_RATIO
    lines = [
        f"IAP against CNN: final return {mean_std(iap['return'])} against {mean_std(cnn['return'])} (bar: IAP's "
        f"mean >= the CNN's mean minus its seed-std, {floor:.1f}), with {ratio:.1f}x fewer parameters "
        f"({iap['parameters']:,} against {cnn['parameters']:,}; bar: >= {MIN_PARAMETER_RATIO:.0f}x): "
        f"{'met' if near else 'not met'}."
    ]
    ceiling = np.mean(blind["walls_passed"]) + np.std(blind["walls_passed"])
    for label in SEEING:
        walls = summaries[label]["walls_passed"]
        above = np.mean(walls) - np.std(walls) > ceiling
        lines.append(
            f"{label} above blind in walls passed per episode: {mean_std(walls, 2)} against "
            f"{mean_std(blind['walls_passed'], 2)} (bar, 'clearly': the mean minus its seed-std above "
            f"blind's mean plus its seed-std, {ceiling:.2f}): {'met' if above else 'not met'}."
        )
    return lines


def table(summaries: dict[str, dict[str, Any]], *, seeds: int) -> str:
    """Markdown: per policy its parameters, final return, walls passed, falls, wall contacts and
    distance per episode (each the mean ± std over finished seeds of the per-seed means over
    the evaluation episodes), how far the runs got; then the bars."""
    lines = [
        "| policy | parameters | final return | walls passed per episode | fell off (share of episodes) | "
        "wall contact steps per episode | distance (m) | seeds finished | iterations | env steps per run |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for label, summary in summaries.items():
        lines.append(
            f"| {label} (`{POLICIES[label]}`) | {summary['parameters']:,} | {mean_std(summary['return'])} | "
            f"{mean_std(summary['walls_passed'], 2)} | {mean_std(summary['fell_off'], 2)} | "
            f"{mean_std(summary['wall_contacts'])} | {mean_std(summary['distance'], 2)} | "
            f"{summary['finished']} of {seeds} | {summary['iterations']} | {summary['env_steps']:,} |"
        )
    return "\n".join([*lines, "", *eyes_closed_table(summaries), *bars(summaries, seeds=seeds)])


def eyes_closed_table(summaries: dict[str, dict[str, Any]]) -> list[str]:
    """Markdown lines (ending in a blank one; none before a seeing run has finished): each seeing
    policy's final return and walls passed with its eyes open and closed on the same courses,
    mean ± std over its finished seeds, and per seed what closing them changes."""
    seeing = [label for label in SEEING if summaries[label]["finished"]]
    if not seeing:
        return []
    lines = [
        "With their eyes closed: the same final checkpoints on the same courses, the high level given a zeroed "
        "image (the condition `policy.blind=true`, as the blind control sees it):",
        "",
        "| policy | final return, eyes open | eyes closed | walls passed per episode, eyes open | eyes closed | "
        "walls passed, open minus closed, per seed |",
        "|---|---:|---:|---:|---:|---|",
    ]
    for label in seeing:
        summary, closed = summaries[label], summaries[label]["eyes_closed"]
        gains = ", ".join(
            f"{open_ - shut:+.2f}" for open_, shut in zip(summary["walls_passed"], closed["walls_passed"])
        )
        lines.append(
            f"| {label} | {mean_std(summary['return'])} | {mean_std(closed['return'])} | "
            f"{mean_std(summary['walls_passed'], 2)} | {mean_std(closed['walls_passed'], 2)} | {gains} |"
        )
    return [*lines, ""]


def plot(rows: list[dict[str, Any]], summaries: dict[str, dict[str, Any]], path: Path) -> Path:
    """Left: each policy's evaluation return per ES iteration, mean and band over its seeds,
    the parameter counts in the legend and title. Right: walls passed per episode on fresh
    courses, mean ± std over finished seeds."""
    from iap_mjx.viz.curves import plot_mean_band, save_png, subplots

    fig, (curves, walls) = subplots(1, 2, figsize=(11, 4), gridspec_kw={"width_ratios": (2, 1)})
    for label, summary in summaries.items():
        runs = [row["curve"] for row in rows if row["policy"] == label]
        if runs:
            plot_mean_band(curves, runs, f"{label} ({summary['parameters']:,} parameters, {len(runs)} seeds)")
    curves.set_xlabel("ES iteration (the centre at its start)")
    curves.set_ylabel("evaluation return (m along the course)")
    curves.set_title(
        f"quadruped-walls: IAP {summaries['IAP']['parameters']:,} parameters, CNN {summaries['CNN']['parameters']:,}"
    )
    curves.legend(fontsize="small")
    labels = list(summaries)
    walls.bar(
        labels,
        [np.mean(summaries[label]["walls_passed"]) if summaries[label]["walls_passed"] else 0.0 for label in labels],
        yerr=[
            np.std(summaries[label]["walls_passed"]) if summaries[label]["walls_passed"] else 0.0 for label in labels
        ],
        capsize=4,
        color=["tab:blue", "tab:orange", "tab:gray"],
    )
    walls.set_ylabel("walls passed per episode (fresh courses)")
    walls.set_title("finished runs, mean ± std over seeds")
    return save_png(fig, path)


def write_results(
    path: Path,
    markdown: str,
    png: Path,
    *,
    seeds: int,
    overrides: tuple[str, ...],
    episodes: int,
    section: str = SECTION,
) -> None:
    """Section ``section`` of ``path``: the command, the figure and the table."""
    options = [*overrides, f"--seeds {seeds}", f"--episodes {episodes}"]
    command = reproduce_command(
        "fig11", options + ([f"--section {section}"] if section != SECTION else []), out=png.parent, results=path
    )
    title = "Figure 11" if section == SECTION else f"Figure 11 (`{section}`)"
    body = (
        f"## {title}: the quadruped on the walled course, IAP against a CNN and a blind high level\n\n"
        f"Command: `{command}`. Curves: the centre's evaluation return at each ES iteration's start, mean "
        f"and std over seeds. Table: each finished run's final centre on {episodes} evaluation episodes of "
        f"courses not seen in training (walls drawn per episode from keys of seed {EVAL_SEED}); per policy "
        f"the mean ± std over seeds of the per-seed means.\n\n![{section}]({tracked_copy(png, path, section)})\n\n"
        f"{markdown}\n"
    )
    write_results_section(path, section, body)
