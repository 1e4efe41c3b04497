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
The keys also fold in the checkpoint's iteration, as the training's own evaluations do: runs of
one budget share their courses, and two budgets' reports (``run.iterations=200`` and ``400``)
are on different ones; ``courses_of=200`` (``--courses-of 200``) plays the later checkpoints on the
earlier courses (``iap_mjx.es.evaluate_run_episodes(..., episodes_of=200)``) and writes
``fig11-courses-of-200.json`` / ``.png`` beside the report on the runs' own courses. Evaluations are
stored in the run directory (``eval.json``, :func:`iap_mjx.paper.evaluations.evaluate_course`),
so a report reads them instead of evaluating again.

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
from iap_mjx.paper import courses
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
    return courses.check("fig11", POLICIES, overrides)


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
    courses_of: int | None = None,
) -> str:
    """Trains (``train=False``: only reads) every policy on ``seeds`` seeds, seed by seed so that
    the policies compare early, evaluates the finished runs on ``episodes`` fresh courses each,
    writes ``fig11.json`` / ``fig11.png`` in ``out_dir`` and returns the markdown table;
    ``results``: a markdown file (RESULTS.md) whose section ``section`` (default ``fig11``; another
    name keeps a second experiment, e.g. from another low level, beside the first) is rewritten
    with it, its figure copied to ``experiments/<section>/``;
    ``export``: a folder (e.g. ``pretrained/quadruped``, tracked by git) that receives each run's
    newest checkpoint, config and metrics as ``<preset>-seed<k>``, finished or not;
    ``courses_of``: the iteration whose evaluation courses the finished runs play (default: their
    own checkpoint's), to compare two budgets on the same courses; the JSON and PNG are then
    ``fig11-courses-of-<k>.*``."""
    require_int("episodes", episodes)
    require_int("seeds", seeds)
    require_int("courses_of", courses_of, minimum=0, none_ok=True)
    check_section_name(section, "fig11-turn")
    checked = check(tuple(overrides))
    out_dir = Path(out_dir)
    stem = "fig11" if courses_of is None else f"fig11-courses-of-{courses_of}"
    rows, summaries = courses.report(
        stem,
        checked,
        POLICIES,
        SEEING,
        STATISTICS,
        out_dir,
        seeds=seeds,
        train=train,
        episodes=episodes,
        export=None if export is None else Path(export),
        courses_of=courses_of,
    )
    png = plot(rows, summaries, out_dir / f"{stem}.png")
    markdown = table(summaries, seeds=seeds)
    if results is not None:
        write_results(
            Path(results),
            markdown,
            png,
            seeds=seeds,
            overrides=tuple(overrides),
            episodes=episodes,
            section=section,
            courses_of=courses_of,
        )
    return markdown


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
    eyes_closed = courses.eyes_closed_table(summaries, SEEING, "walls_passed", "walls passed")
    return "\n".join([*lines, "", *eyes_closed, *bars(summaries, seeds=seeds)])


def plot(rows: list[dict[str, Any]], summaries: dict[str, dict[str, Any]], path: Path) -> Path:
    """Each policy's curves, the parameter counts in the title, and walls passed per episode on
    fresh courses (:func:`iap_mjx.paper.courses.plot`)."""
    title = (
        f"quadruped-walls: IAP {summaries['IAP']['parameters']:,} parameters, CNN {summaries['CNN']['parameters']:,}"
    )
    return courses.plot(
        rows,
        summaries,
        path,
        title=title,
        statistic="walls_passed",
        what="walls passed",
        colours=("tab:blue", "tab:orange", "tab:gray"),
    )


def write_results(
    path: Path,
    markdown: str,
    png: Path,
    *,
    seeds: int,
    overrides: tuple[str, ...],
    episodes: int,
    section: str = SECTION,
    courses_of: int | None = None,
) -> None:
    """Section ``section`` of ``path``: the command, the figure and the table."""
    options = [*overrides, f"--seeds {seeds}", f"--episodes {episodes}"]
    options += [f"--courses-of {courses_of}"] if courses_of is not None else []
    command = reproduce_command(
        "fig11", options + ([f"--section {section}"] if section != SECTION else []), out=png.parent, results=path
    )
    drawn = f"seed {EVAL_SEED} and the checkpoint's iteration"
    if courses_of is not None:
        drawn = (
            f"seed {EVAL_SEED} and iteration {courses_of}: the courses of a {courses_of}-iteration checkpoint's report"
        )
    title = "Figure 11" if section == SECTION else f"Figure 11 (`{section}`)"
    body = (
        f"## {title}: the quadruped on the walled course, IAP against a CNN and a blind high level\n\n"
        f"Command: `{command}`. Curves: the centre's evaluation return at each ES iteration's start, mean "
        f"and std over seeds. Table: each finished run's final centre on {episodes} evaluation episodes of "
        f"courses not seen in training (walls drawn per episode from keys of {drawn}); per policy "
        f"the mean ± std over seeds of the per-seed means.\n\n![{section}]({tracked_copy(png, path, section)})\n\n"
        f"{markdown}\n"
    )
    write_results_section(path, section, body)
