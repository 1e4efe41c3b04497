"""The run directories under a folder, one line each: what a run trains, how far it has got and
what its evaluations gave, read from its files (``config.json``, ``metrics.jsonl``,
``eval.json``, the checkpoints' steps) without building or compiling anything
(``iap-mjx runs``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from iap_mjx.configs.training import EVAL_SEED
from iap_mjx.es import checkpoint
from iap_mjx.es.metrics_log import (
    CONFIG_FILE,
    EVAL_FILE,
    entry_returns,
    parse_evaluation_key,
    read_config,
    read_history,
)


@dataclasses.dataclass(frozen=True)
class ListedRun:
    """One run directory as ``iap-mjx runs`` lists it.

    Attributes:
      path: the run directory.
      env, policy: its config's env name and policy kind (a hierarchical policy's with its
        high level, and ``blind`` when that sees a zeroed image).
      seed: its config's ``run.seed``.
      parameters: the policy's trainable parameters (``metrics.jsonl``'s column; ``None``
        without a row, or for runs logged before the column existed).
      step, iterations: its newest checkpoint (``None`` before the first) and the iterations
        its config asks for.
      eval_return: the last evaluation return logged up to the newest checkpoint (the centre
        at the start of that checkpoint's last iteration; ``None`` without a row).
      evaluations: ``{name: (mean return, episodes)}`` of the ``eval.json`` entries of the
        newest checkpoint on the evaluation seed (``train``, ``held-out``, ``course``, ...; of
        several with one name, the one with the most episodes), in the file's order.
    """

    path: Path
    env: str
    policy: str
    seed: int
    parameters: int | None
    step: int | None
    iterations: int
    eval_return: float | None
    evaluations: dict[str, tuple[float, int]]

    @property
    def finished(self) -> bool:
        """Whether the newest checkpoint is the config's last iteration (a run stopped by
        ``run.max_minutes`` is not)."""
        return self.step is not None and self.step >= self.iterations


def run_dirs(folder: str | Path) -> list[Path]:
    """Every run directory (a ``config.json``, which training writes first) in ``folder`` or
    below it, sorted."""
    return sorted(path.parent for path in Path(folder).rglob(CONFIG_FILE))


def listed(run_dir: str | Path) -> ListedRun:
    """:class:`ListedRun` of one run directory (``ValueError`` naming the file that does not
    hold what a run writes)."""
    run_dir = Path(run_dir)
    step = checkpoint.latest_step(run_dir)
    try:
        config = read_config(run_dir)
        options = config["policy"]["options"]
        policy = config["policy"]["kind"]
        env, seed, iterations = config["env"]["name"], int(config["run"]["seed"]), int(config["run"]["iterations"])
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{run_dir / CONFIG_FILE}: not a run's config ({error!r})") from None
    if "high_level" in options:
        policy += f" ({options['high_level']}{', blind' if options.get('blind') else ''})"
    history = read_history(run_dir, up_to=step) if step is not None else []
    last = history[-1] if history else {}
    return ListedRun(
        path=run_dir,
        env=env,
        policy=policy,
        seed=seed,
        parameters=int(last["parameters"]) if "parameters" in last else None,
        step=step,
        iterations=iterations,
        eval_return=float(last["eval_return"]) if "eval_return" in last else None,
        evaluations=_evaluations(run_dir, step) if step is not None else {},
    )


def _evaluations(run_dir: Path, step: int) -> dict[str, tuple[float, int]]:
    """:attr:`ListedRun.evaluations` from ``run_dir``'s :data:`EVAL_FILE`."""
    path = run_dir / EVAL_FILE
    try:
        stored = json.loads(path.read_text()) if path.exists() else {}
        found: dict[str, tuple[float, int]] = {}
        for key, entry in stored.items():
            name, at, episodes, seed = parse_evaluation_key(key)
            returns = entry_returns(entry)
            if at == step and seed == EVAL_SEED and episodes >= found.get(name, (0.0, 0))[1]:
                found[name] = (float(np.mean(returns)), episodes)
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{path}: not a run's evaluations ({error!r})") from None
    return found


def table(runs: list[ListedRun], relative_to: str | Path | None = None) -> str:
    """Markdown: one row per run, paths relative to ``relative_to`` when given (the folder
    itself by its name)."""
    lines = [
        "| run | env | policy | seed | parameters | checkpoint / iterations | last logged eval return | "
        "stored evaluations of the checkpoint: mean return (episodes) |",
        "|---|---|---|---:|---:|---|---:|---|",
    ]
    for run in runs:
        path = run.path
        if relative_to is not None:
            path = run.path.relative_to(relative_to) if run.path != Path(relative_to) else Path(run.path.name)
        parameters = f"{run.parameters:,}" if run.parameters is not None else "-"
        progress = f"{run.step if run.step is not None else 'none yet'} / {run.iterations}"
        progress += "" if run.finished else " (unfinished)"
        eval_return = f"{run.eval_return:.1f}" if run.eval_return is not None else "-"
        lines.append(
            f"| `{path}` | {run.env} | {run.policy} | {run.seed} | {parameters} | {progress} | {eval_return} | "
            f"{_stored(run.evaluations)} |"
        )
    return "\n".join(lines)


def _stored(evaluations: dict[str, tuple[float, int]]) -> str:
    """``train 198.8, held-out 189.0 (20 each)``, or each with its own count when they differ."""
    if not evaluations:
        return "-"
    counts = {episodes for _, episodes in evaluations.values()}
    if len(counts) == 1:
        means = ", ".join(f"{name} {mean:.1f}" for name, (mean, _) in evaluations.items())
        return f"{means} ({counts.pop()} each)" if len(evaluations) > 1 else f"{means} ({counts.pop()})"
    return ", ".join(f"{name} {mean:.1f} ({episodes})" for name, (mean, episodes) in evaluations.items())
