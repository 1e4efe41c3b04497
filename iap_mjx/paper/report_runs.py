"""The training runs behind every figure and table: their configs checked before anything
compiles, trained (or resumed) in their own run directory, read back as a report's row, and
their policies built without compiling, so that a report is reproduced by running it again and
a finished run is never trained twice."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from iap_mjx import configs


def check_evaluated(report: str, checked: Iterable[configs.TrainConfig]) -> None:
    """``ValueError`` unless every config evaluates its centre (``run.eval_episodes >= 1``):
    ``report``'s curves and tables read the evaluation return."""
    if any(config.run.eval_episodes < 1 for config in checked):
        raise ValueError(f"{report} reads the evaluation return: run.eval_episodes must be >= 1")


def check_not_swept(report: str, overrides: Iterable[str], swept: Iterable[str], what: str) -> None:
    """``ValueError`` naming every override of a setting in ``swept`` (e.g. ``policy.patch_size``),
    which ``report`` sets itself per run (``what``, e.g. "the kernel and patch size per curve");
    a key without its section counts too (``seed=1`` is ``run.seed``)."""
    swept = tuple(swept)
    given = [item for item in overrides if configs.override_path(item) in swept]
    if given:
        raise ValueError(f"{report} sets {what}; remove {', '.join(given)}")


def check_seed_not_set(report: str, overrides: Iterable[str]) -> None:
    """``ValueError`` naming a ``run.seed`` override (``seed=...`` too): every report sets each
    run's seed itself, so the override would be replaced without a word."""
    what = "each run's seed itself (how many: seeds, --seeds on the command line, where it has them)"
    check_not_swept(report, overrides, ("run.seed",), what)


def train_command(preset: str, overrides: Iterable[str], seed: int, run_dir: Path | None = None) -> str:
    """The ``iap-mjx train`` command line of one run, as a report's table shows it: ``preset``,
    ``overrides`` (the caller's, then the run's own), ``run.seed=<seed>`` and, given, ``--run-dir``;
    joined with spaces, unquoted."""
    words = ["iap-mjx train", preset, *overrides, f"run.seed={seed}"]
    if run_dir is not None:
        words.append(f"--run-dir {run_dir}")
    return " ".join(words)


def trained_curve(
    config: configs.TrainConfig, seed: int, run_dir: Path, *, train: bool = True
) -> tuple[list[float], float] | None:
    """Trains ``config`` with ``seed`` in ``run_dir`` (resuming from its checkpoint, so a
    finished run is not trained again).

    Returns the centre's evaluation return at the start of iterations ``1..run.iterations``
    (a run directory trained further is cut there) and the seconds those iterations took:
    their run times summed over every session, plus the first session's compile. With
    ``train=False`` nothing is trained: the run's rows up to its last checkpoint are read.
    ``None`` while the run has no iteration to report (no checkpoint, or none of its rows).
    """
    from iap_mjx.es import checkpoint
    from iap_mjx.es.metrics_log import read_history

    if train:
        from iap_mjx.es import train as train_es

        config = dataclasses.replace(config, run=dataclasses.replace(config.run, seed=seed))
        history = train_es(config, run_dir=run_dir, progress=False).history
    else:
        step = checkpoint.latest_step(run_dir)
        if step is None:
            return None
        history = read_history(run_dir, up_to=step)
    history = history[: config.run.iterations]
    if not history:
        return None
    seconds = sum(row["run_s"] for row in history) + history[0]["compile_s"]
    return [float(row["eval_return"]) for row in history], seconds


def run_summary(
    config: configs.TrainConfig, seed: int, run_dir: Path, *, train: bool = True
) -> tuple[dict[str, Any], list[dict[str, Any]]] | None:
    """:func:`trained_curve`'s run as a report's row, ``{"seed", "curve", "seconds",
    "iterations", "env_steps", "finished"}`` (``env_steps``: the training steps of its last
    iteration), and its metrics rows up to that iteration; ``None`` while it has none."""
    from iap_mjx.es.metrics_log import read_history

    trained = trained_curve(config, seed, run_dir, train=train)
    if trained is None:
        return None
    curve, seconds = trained
    history = read_history(run_dir, up_to=len(curve))
    row = {
        "seed": seed,
        "curve": curve,
        "seconds": seconds,
        "iterations": len(curve),
        "env_steps": int(history[-1]["env_steps"]),
        "finished": len(curve) == config.run.iterations,
    }
    return row, history


def reported_run(
    config: configs.TrainConfig,
    seed: int,
    run_dir: Path,
    *,
    train: bool = True,
    evaluate: Callable[[Path, int], dict[str, Any]] | None = None,
    export: Path | None = None,
) -> tuple[dict[str, Any], list[dict[str, Any]]] | None:
    """:func:`run_summary`, with a finished run's ``evaluate(run_dir, latest step)`` entries
    added to its row; then, with ``export``, the run's newest checkpoint and files (its
    evaluations' ``eval.json`` included) copied to ``export``, finished or not."""
    from iap_mjx.es import checkpoint

    summary = run_summary(config, seed, run_dir, train=train)
    if summary is None:
        return None
    row, history = summary
    if row["finished"] and evaluate is not None:
        step = checkpoint.latest_step(run_dir)
        assert step is not None  # a finished run has its final checkpoint
        row.update(evaluate(run_dir, step))
    if export is not None:
        checkpoint.export_latest(run_dir, export)
    return row, history


def built_policies(checked: dict[Any, configs.TrainConfig]) -> dict[Any, Any]:
    """The policy each config builds, constructed (so validated) and nothing compiled; each
    distinct env is built once (the quadruped's takes seconds)."""
    from iap_mjx.es import make_env_and_policy

    built_envs: dict[tuple[str, Any], Any] = {}
    out = {}
    for name, config in checked.items():
        spec = (config.env.name, config.env.overrides)
        env, out[name] = make_env_and_policy(config, env=built_envs.get(spec))
        built_envs[spec] = env
    return out
