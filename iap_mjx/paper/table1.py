"""Reproducing the paper's Table 1 (Distracting Control Suite, static, medium) and measuring
what it does not: generalisation of the same policies to other conditions.

For each suite task, ``dcs-<task>`` trains on several seeds, each in its own run directory
``<out>/dcs-<task>-seed<k>`` (resumed from its checkpoint, skipped once finished; the
training loop is :func:`iap_mjx.paper.report_runs.trained_curve`'s). A finished run's final centre is
then evaluated, ``episodes`` episodes per condition, each episode with its own draw:

- ``train``: the training condition (static medium distractions, training backgrounds);
- ``held-out``: the same, on backgrounds never shown in training (``env.background_videos=val``);
- ``dynamic``: dynamic medium distractions (``env.dynamic=true``);
- ``none``: no distraction (``env.distraction=none``).

Each evaluation is stored in the run directory (``eval.json``, keyed by condition, checkpoint,
episodes and seed), so a report reads it instead of evaluating again. Writes
``<out>/table1.json`` and ``<out>/table1.png`` and returns the markdown table, next to the
paper's SAC and QT-Opt baselines.

``policy="cnn"`` trains the same-budget convolutional baseline instead (``dcs-<task>-cnn``,
run directories ``dcs-<task>-cnn-seed<k>``, the same ES, frames and controller) and reports it
beside the IAP runs of the same tasks found in ``out`` (``table1-cnn.json``/``.png``, section
``table1-cnn``), parameter counts included.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from iap_mjx import configs
from iap_mjx.checks import require_int
from iap_mjx.configs.distraction import TASKS
from iap_mjx.configs.overrides import apply_condition
from iap_mjx.files import write_json
from iap_mjx.paper.evaluations import evaluate_conditions, seed_means
from iap_mjx.paper.report_runs import built_policies, check_evaluated, check_seed_not_set, reported_run
from iap_mjx.sections import check_section_name, mean_std, reproduce_command, tracked_copy, write_results_section

# The IAP paper's Table 1 (static, medium; from Stone et al. 2021): SAC, QT-Opt.
BASELINES = {
    "cheetah-run": (77.0, 74.0),
    "walker-walk": (24.0, 111.0),
    "cartpole-swingup": (196.0, 167.0),
    "ball_in_cup-catch": (109.0, 62.0),
    "reacher-easy": (75.0, 109.0),
}
# The best six-task static-medium mean the suite's own paper reports (QT-Opt with DrQ
# augmentation, 500k env steps).
SUITE_BEST_MEAN, SUITE_BEST_STEPS = 170.0, 500_000
CONDITIONS = {
    "train": (),
    "held-out": ("env.background_videos=val",),
    "dynamic": ("env.dynamic=true",),
    "none": ("env.distraction=none",),
}


PRESET_SUFFIXES = {"iap": "", "cnn": "-cnn"}
"""The policies a table can train, and their presets' suffix (``dcs-<task><suffix>``)."""
SECTION = "table1"  # the RESULTS.md section and experiments/ folder written by default


def preset(task: str, policy: str = "iap") -> str:
    return f"dcs-{task}{PRESET_SUFFIXES[policy]}"


def parameters(config: configs.TrainConfig) -> int:
    """The trainable parameters of a config's policy, built for its env's observation as
    training builds it (a frame stack or a depth channel counts), on undistracted frames: the
    distraction changes no shape, and its backgrounds are not loaded for a count."""
    from iap_mjx import policies

    undistracted = apply_condition(config, CONDITIONS["none"])
    return policies.init_param_count(built_policies({None: undistracted})[None])


def check(tasks: tuple[str, ...], overrides: tuple[str, ...], policy: str = "iap") -> dict[str, configs.TrainConfig]:
    """Every task's config and every condition's env, validated before anything compiles."""
    from iap_mjx import envs

    check_seed_not_set("table1", overrides)
    if policy not in PRESET_SUFFIXES:
        raise ValueError(f"policy {policy!r}: choose from {', '.join(PRESET_SUFFIXES)}")
    unknown = [task for task in tasks if task not in TASKS]
    if unknown or not tasks:
        raise ValueError(f"tasks {list(tasks)}: choose from {', '.join(TASKS)}")
    result = {}
    for task in tasks:
        config = configs.apply_overrides(configs.get(preset(task, policy)), overrides)
        check_evaluated("table1", [config])
        for condition in CONDITIONS.values():
            probe = apply_condition(config, condition)
            envs.check_spec(probe.env)
        result[task] = config
    return result


def control_steps(config: configs.TrainConfig, env_steps: int) -> int:
    """``env_steps`` (``metrics.csv``'s: ``env.step`` calls, one action each) as the suite's
    paper, PlaNet and DrQ count a budget: dm_control control steps, ``action_repeat`` per action
    (cheetah-run's 1000-step episode is 250 actions at action repeat 4)."""
    from iap_mjx import envs

    return env_steps * envs.check_spec(config.env).action_repeat


def run_row(
    task: str,
    config: configs.TrainConfig,
    seed: int,
    out_dir: Path,
    *,
    train: bool,
    episodes: int,
    parameter_count: int,
    export: Path | None = None,
    policy: str = "iap",
) -> dict[str, Any] | None:
    """One run: its curve, env steps (``control_steps``, :func:`control_steps`), seconds, and
    (finished runs) every condition's returns; ``parameter_count`` (:func:`parameters`) goes
    in its row; with ``export``, its newest checkpoint and files are copied to
    ``export/<task><suffix>-seed<k>`` (``suffix``: :data:`PRESET_SUFFIXES`)."""
    reported = reported_run(
        config,
        seed,
        out_dir / f"{preset(task, policy)}-seed{seed}",
        train=train,
        evaluate=lambda run_dir, step: {
            "conditions": evaluate_conditions(run_dir, step, episodes=episodes, conditions=CONDITIONS)
        },
        export=None if export is None else export / f"{task}{PRESET_SUFFIXES[policy]}-seed{seed}",
    )
    if reported is None:
        return None
    row = {"task": task, "policy": policy, "parameters": parameter_count, **reported[0]}
    row["control_steps"] = control_steps(config, row["env_steps"])
    return row


def collect_rows(
    task_configs: dict[str, configs.TrainConfig], seeds: int, out_dir: Path, **kwargs: Any
) -> list[dict[str, Any]]:
    """:func:`run_row` of every task and seed (task by task) that has a run; ``kwargs`` go to it.
    Each task's policy is built once, for its parameter count."""
    rows = []
    for task, config in task_configs.items():
        count = parameters(config)
        for seed in range(seeds):
            if (row := run_row(task, config, seed, out_dir, parameter_count=count, **kwargs)) is not None:
                rows.append(row)
    return rows


def iap_beside(tasks: tuple[str, ...], overrides: tuple[str, ...], out_dir: Path) -> dict[str, configs.TrainConfig]:
    """The IAP configs a CNN table reads beside its own runs: per task, the config its first IAP
    run with a checkpoint in ``out_dir`` trained with (an IAP setting may hold options the CNN
    cannot take, e.g. ``policy.with_patches``), else ``dcs-<task>`` with ``overrides``."""
    from iap_mjx.es import checkpoint
    from iap_mjx.es.results import trained_config

    out = check(tasks, overrides)
    for task in tasks:
        trained = [d for d in sorted(out_dir.glob(f"{preset(task)}-seed*")) if checkpoint.latest_step(d) is not None]
        if trained:
            out[task] = trained_config(trained[0])
    return out


def reproduce_table1(
    out_dir: str | Path,
    *,
    seeds: int = 3,
    overrides: tuple[str, ...] = (),
    episodes: int = 20,
    train: bool = True,
    tasks: tuple[str, ...] = TASKS,
    results: str | Path | None = None,
    export: str | Path | None = None,
    policy: str = "iap",
    section: str = SECTION,
) -> str:
    """Trains (``train=False``: only reads) every task and seed, evaluates the finished runs,
    writes ``<name>.json`` / ``<name>.png`` in ``out_dir`` (``name``: ``section``, default
    ``table1``, with ``-cnn`` appended for ``policy="cnn"``; another section keeps a second
    setting's table beside the first) and returns the markdown table; ``results``: a
    markdown file (RESULTS.md) whose ``<name>`` section is rewritten with it; ``export``: a
    folder (e.g. ``pretrained/dcs``, tracked by git) that receives each run's newest checkpoint,
    config and metrics as ``<task><suffix>-seed<k>`` as soon as the run is trained (finished or
    not), so trained policies ship and unfinished runs survive a lost ``out_dir``."""
    require_int("episodes", episodes)
    require_int("seeds", seeds)
    check_section_name(section, "table1-fs2")
    task_configs = check(tuple(tasks), tuple(overrides), policy)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    export = None if export is None else Path(export)
    rows = collect_rows(task_configs, seeds, out_dir, train=train, episodes=episodes, export=export, policy=policy)
    if not rows:
        raise ValueError(f"no table1 {policy} runs in {out_dir} to report")
    name = section + PRESET_SUFFIXES[policy]
    write_json(out_dir / f"{name}.json", rows)
    png = plot(rows, out_dir / f"{name}.png")
    if policy == "iap":
        markdown = table(rows, seeds=seeds)
    else:  # beside the IAP runs of the same tasks, read (and evaluated) but never trained here
        iap = collect_rows(
            iap_beside(tuple(tasks), tuple(overrides), out_dir), seeds, out_dir, train=False, episodes=episodes
        )
        markdown = comparison(rows, iap, seeds=seeds)
    if results is not None:
        write_results(
            Path(results),
            markdown,
            png,
            seeds=seeds,
            overrides=tuple(overrides),
            episodes=episodes,
            policy=policy,
            tasks=tuple(tasks),
            section=section,
        )
    return markdown


def _mean_seconds(finished: list[dict[str, Any]]) -> str:
    """The table's wall-clock per run: the mean over the finished runs only (an unfinished run's
    seconds cover part of the budget), ``-`` before the first finishes."""
    return f"{np.mean([row['seconds'] for row in finished]):.0f}" if finished else "-"


def write_results(
    path: Path,
    markdown: str,
    png: Path,
    *,
    seeds: int,
    overrides: tuple[str, ...],
    episodes: int,
    policy: str = "iap",
    tasks: tuple[str, ...] = TASKS,
    section: str = SECTION,
) -> None:
    """The ``<section>`` (or ``<section>-cnn``) section of ``path``: the command, the table and
    the curves."""
    name = section + PRESET_SUFFIXES[policy]
    options = [*overrides, f"--seeds {seeds}", f"--episodes {episodes}"]
    if tuple(tasks) != TASKS:  # the command reproduces these tasks only
        options.append("--tasks " + ",".join(tasks))
    if section != SECTION:
        options.append(f"--section {section}")
    command = reproduce_command(
        "table1", options + ([f"--policy {policy}"] if policy != "iap" else []), out=png.parent, results=path
    )
    image = tracked_copy(png, path, name)
    label = "" if section == SECTION else f" (`{name}`)"  # e.g. "## Table 1 (`table1-fs2`): ..."
    if policy == "iap":
        title = (
            f"## Table 1{label}: the Distracting Control Suite, static medium\n\nCommand: `{command}`. Return: "
            f"the final centre's mean over {episodes} evaluation episodes per seed, each with its own draw "
            "of the condition; mean ± std over seeds. SAC and QT-Opt: the IAP paper's Table 1 (from "
            "Stone et al. 2021)."
        )
    else:
        title = (
            f"## Table 1's baseline{label}: convolutions against attention, the same budget\n\nCommand: "
            f"`{command}`. The `dcs-<task>-cnn` presets: the same frames, ES setting, iterations and "
            "LSTM(16) controller as `dcs-<task>`, with three convolutions, a max pool and a dense "
            f"embedding in place of the attention. Return: the final centre's mean over {episodes} "
            "evaluation episodes per seed; mean ± std over seeds."
        )
    body = f"{title}\n\n![{name}]({image})\n\n{markdown}\n"
    write_results_section(path, name, body)


def table(rows: list[dict[str, Any]], *, seeds: int) -> str:
    """Markdown: per task the paper's baselines, our final return in the training condition
    (mean ± std over seeds; the per-seed means of ``episodes`` evaluation episodes), the other
    conditions, env steps (dm_control's control steps) and wall-clock; then the bar's summary."""
    lines = [
        "| task | SAC | QT-Opt | IAP (ours), train condition | per seed | held-out backgrounds | "
        "dynamic | no distraction | seeds finished | iterations | env steps per run (control steps: actions "
        "x action repeat) | wall-clock per run (s) "
        "| parameters |",
        "|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    met, means = 0, {}
    for task in TASKS:
        task_rows = [row for row in rows if row["task"] == task]
        if not task_rows:
            continue
        done = [row for row in task_rows if row["finished"]]
        per = seed_means(task_rows, "conditions", CONDITIONS)
        sac, qt = BASELINES.get(task, (None, None))
        if len(done) == seeds:
            means[task] = float(np.mean(per["train"]))
            met += task in BASELINES and means[task] >= max(BASELINES[task])
        lines.append(
            f"| {task} | {sac if sac is not None else '-'} | {qt if qt is not None else '-'} | "
            f"{mean_std(per['train'])} | {', '.join(f'{v:.1f}' for v in per['train']) or '-'} | "
            f"{mean_std(per['held-out'])} | {mean_std(per['dynamic'])} | {mean_std(per['none'])} | "
            f"{len(done)} of {seeds} | {max(row['iterations'] for row in task_rows)} | "
            f"{max(row['control_steps'] for row in task_rows):,} | {_mean_seconds(done)} | "
            f"{task_rows[0]['parameters']:,} |"
        )
    scored = [task for task in BASELINES if task in means]
    lines.append("")
    lines.append(f"At or above the better of SAC and QT-Opt: {met} of {len(scored)} finished tasks (bar: 4 of 5).")
    if len(means) == len(TASKS):
        lines.append(
            f"Six-task mean: {np.mean(list(means.values())):.1f} (bar: {SUITE_BEST_MEAN:.0f}, the suite "
            f"paper's best, at {SUITE_BEST_STEPS:,} env steps; ours above, per run)."
        )
    return "\n".join(lines)


def comparison(cnn: list[dict[str, Any]], iap: list[dict[str, Any]], *, seeds: int) -> str:
    """Markdown: per task, the parameter counts and each policy's returns in the training
    condition and on held-out backgrounds (mean ± std over finished seeds), then the CNN's in
    the other two conditions."""
    lines = [
        "| task | IAP parameters | IAP, train | IAP, held-out | CNN parameters | CNN, train | CNN, held-out "
        "| CNN, dynamic | CNN, no distraction | seeds finished (IAP, CNN) | iterations |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for task in TASKS:
        ours = [row for row in cnn if row["task"] == task]
        if not ours:
            continue
        theirs = [row for row in iap if row["task"] == task]
        per = {
            policy: seed_means(task_rows, "conditions", CONDITIONS)
            for policy, task_rows in (("iap", theirs), ("cnn", ours))
        }
        counts = [f"{task_rows[0]['parameters']:,}" if task_rows else "-" for task_rows in (theirs, ours)]
        finished = [sum(row["finished"] for row in task_rows) for task_rows in (theirs, ours)]
        lines.append(
            f"| {task} | {counts[0]} | {mean_std(per['iap']['train'])} | {mean_std(per['iap']['held-out'])} | "
            f"{counts[1]} | {mean_std(per['cnn']['train'])} | {mean_std(per['cnn']['held-out'])} | "
            f"{mean_std(per['cnn']['dynamic'])} | {mean_std(per['cnn']['none'])} | "
            f"{finished[0]} and {finished[1]} of {seeds} | {max(row['iterations'] for row in ours)} |"
        )
    return "\n".join(lines)


def plot(rows: list[dict[str, Any]], path: Path) -> Path:
    """One panel per task: each seed's evaluation-return curve and the baselines as lines."""
    from iap_mjx.viz.curves import save_png, subplots

    tasks = [task for task in TASKS if any(row["task"] == task for row in rows)]
    fig, axes = subplots(1, len(tasks), figsize=(3.6 * len(tasks), 3.2), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        for row in rows:
            if row["task"] == task:
                ax.plot(np.arange(1, len(row["curve"]) + 1), row["curve"], label=f"seed {row['seed']}")
        for value, name, style in zip(BASELINES.get(task, ()), ("SAC", "QT-Opt"), ("--", ":")):
            ax.axhline(value, color="grey", linestyle=style, label=name)
        ax.set_title(task)
        ax.set_xlabel("ES iteration")
    axes[0][0].set_ylabel("evaluation return (static medium)")
    axes[0][0].legend(fontsize="small")
    return save_png(fig, path)
