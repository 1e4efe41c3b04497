"""The run directories under a folder, one line each: what a run trains, how far it has got and
what its evaluations gave, read from its files (``config.json``, ``metrics.jsonl``,
``eval.json``, the checkpoints' steps) without building or compiling anything
(``iap-mjx runs``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from iap_mjx.es import checkpoint
from iap_mjx.es.metrics_log import CONFIG_FILE, EVAL_FILE, read_config, read_history


@dataclasses.dataclass(frozen=True)
class RunSummary:
    """One run directory.

    Attributes:
      path: the run directory.
      env, policy: its config's env name and policy kind (a hierarchical policy's with its
        high level, and ``blind`` when that sees a zeroed image).
      seed: its config's ``run.seed``.
      parameters: the policy's trainable parameters (``metrics.jsonl``'s column; ``None``
        without a row, or for runs logged before the column existed).
      step, iterations: its newest checkpoint and the iterations its config asks for.
      eval_return: the last evaluation return logged up to the newest checkpoint (the centre
        at the start of that checkpoint's last iteration; ``None`` without a row).
      evaluations: ``{name: mean return}`` of the ``eval.json`` entries of the newest
        checkpoint (``train``, ``held-out``, ``course``, ...), in the file's order.
    """

    path: Path
    env: str
    policy: str
    seed: int
    parameters: int | None
    step: int
    iterations: int
    eval_return: float | None
    evaluations: dict[str, float]

    @property
    def finished(self) -> bool:
        return self.step >= self.iterations


def run_dirs(folder: str | Path) -> list[Path]:
    """Every run directory (a ``config.json`` and a checkpoint) in ``folder`` or below it, sorted."""
    folder = Path(folder)
    found = [path.parent for path in folder.rglob(CONFIG_FILE) if checkpoint.latest_step(path.parent) is not None]
    return sorted(found)


def summarise(run_dir: str | Path) -> RunSummary:
    """:class:`RunSummary` of one run directory (``FileNotFoundError`` without a checkpoint)."""
    run_dir = Path(run_dir)
    step = checkpoint.latest_step(run_dir)
    if step is None:
        raise FileNotFoundError(f"no checkpoint in {run_dir}")
    config = read_config(run_dir)
    history = read_history(run_dir, up_to=step)
    options = config["policy"]["options"]
    policy = config["policy"]["kind"]
    if "high_level" in options:
        policy += f" ({options['high_level']}{', blind' if options.get('blind') else ''})"
    stored = json.loads((run_dir / EVAL_FILE).read_text()) if (run_dir / EVAL_FILE).exists() else {}
    evaluations = {}
    for key, entry in stored.items():
        name, _, rest = key.partition("@")
        if rest.split("x")[0] == str(step):
            evaluations[name] = float(np.mean(entry["return"] if isinstance(entry, dict) else entry))
    return RunSummary(
        path=run_dir,
        env=config["env"]["name"],
        policy=policy,
        seed=int(config["run"]["seed"]),
        parameters=int(history[-1]["parameters"]) if history and "parameters" in history[-1] else None,
        step=step,
        iterations=int(config["run"]["iterations"]),
        eval_return=float(history[-1]["eval_return"]) if history and "eval_return" in history[-1] else None,
        evaluations=evaluations,
    )


def table(summaries: list[RunSummary], relative_to: str | Path | None = None) -> str:
    """Markdown: one row per run, paths relative to ``relative_to`` when given."""
    lines = [
        "| run | env | policy | seed | parameters | checkpoint / iterations | last logged eval return | "
        "stored evaluations of the checkpoint (mean return) |",
        "|---|---|---|---:|---:|---|---:|---|",
    ]
    for run in summaries:
        path = run.path.relative_to(relative_to) if relative_to is not None else run.path
        parameters = f"{run.parameters:,}" if run.parameters is not None else "-"
        progress = f"{run.step} / {run.iterations}" + ("" if run.finished else " (unfinished)")
        eval_return = f"{run.eval_return:.1f}" if run.eval_return is not None else "-"
        stored = ", ".join(f"{name} {value:.1f}" for name, value in run.evaluations.items()) or "-"
        lines.append(
            f"| `{path}` | {run.env} | {run.policy} | {run.seed} | {parameters} | {progress} | {eval_return} | {stored} |"
        )
    return "\n".join(lines)
