"""What a run directory holds for a person: ``config.json`` (the resolved config, written
when training starts) and the per-iteration metrics: ``metrics.jsonl``, ``metrics.csv`` and
TensorBoard events.

Columns: ``env_steps`` counts training steps so far (population x episodes x horizon, the
sample budget), each an ``env.step`` call, one action: a dm_control task with action repeat
``k`` simulates ``k`` of its control steps per env step, and PlaNet, DrQ and the Distracting
Control Suite count those (``iap_mjx.paper.table1.control_steps``); ``return_*`` are over the
population's fitness (mean return per member);
``eval_return``/``eval_return_std`` over the centre's evaluation episodes at the start of the
iteration; ``parameters`` is the policy's number of trainable scalars (the same in every row),
``params_norm`` the L2 norm of the centre's and ``sigma`` OpenES's noise scale at the iteration
(empty for an evosax strategy);
``nan_episodes`` counts population episodes that met a bad state; ``contact_saturated_episodes``
counts population episodes that filled every MJX contact slot at some step (a contact may have
been dropped: raise ``env.max_contacts`` if it is not 0); ``env_steps_per_s`` counts
every simulated step (training, evaluation, padding) per second of run time; ``run_s`` is one
iteration's run time, ``compile_s`` the compile time so far, ``wall_s`` the time since
``train`` started (this session). An env with per-episode statistics (``episode_metrics``, e.g.
the quadruped course's ``walls_passed``) adds two columns per statistic after
``contact_saturated_episodes`` (:func:`metric_columns`): ``<name>_mean`` over the population's
episodes and ``eval_<name>`` over the centre's evaluation episodes.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import re
from pathlib import Path
from typing import Any

from iap_mjx.files import write_json, write_text

logger = logging.getLogger(__name__)

# The files of a run directory besides its checkpoints (``iap_mjx.es.checkpoint.RUN_FILES``).
CONFIG_FILE = "config.json"
METRICS_JSONL = "metrics.jsonl"
METRICS_CSV = "metrics.csv"
EVAL_FILE = "eval.json"  # the evaluations kept beside a checkpoint: ``iap_mjx.paper.evaluations``

COLUMNS = (
    "iteration",
    "env_steps",
    "return_mean",
    "return_max",
    "return_min",
    "return_std",
    "eval_return",
    "eval_return_std",
    "nan_episodes",
    "contact_saturated_episodes",
    "sigma",
    "params_norm",
    "parameters",
    "env_steps_per_s",
    "run_s",
    "compile_s",
    "wall_s",
)


def metric_columns(episode_metrics: tuple[str, ...] = ()) -> tuple[str, ...]:
    """:data:`COLUMNS` with ``<name>_mean`` and ``eval_<name>`` for each of an env's
    per-episode statistics, after ``contact_saturated_episodes``."""
    at = COLUMNS.index("contact_saturated_episodes") + 1
    extra = tuple(column for name in episode_metrics for column in (f"{name}_mean", f"eval_{name}"))
    return COLUMNS[:at] + extra + COLUMNS[at:]


def write_config(run_dir: str | Path, config: dict[str, Any]) -> Path:
    """Writes ``config`` (``TrainConfig.to_dict()``) as ``run_dir/config.json``, atomically."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    path = run_dir / CONFIG_FILE
    write_json(path, config, indent=2)
    return path


def read_config(run_dir: str | Path) -> dict[str, Any]:
    """``run_dir/config.json`` as written by :func:`write_config`."""
    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        raise FileNotFoundError(f"no {CONFIG_FILE} in {run_dir}")
    return json.loads(path.read_text())


def read_history(run_dir: str | Path, up_to: int | None = None) -> list[dict[str, Any]]:
    """The rows of ``metrics.jsonl`` (only iterations ``<= up_to`` when given).

    A last line cut short (the process died mid-write) is dropped with a warning: its
    iteration is past the last checkpoint, so resuming recomputes it.
    """
    path = Path(run_dir) / METRICS_JSONL
    if not path.exists():
        return []
    lines = [line for line in path.read_text().splitlines() if line.strip()]
    rows = []
    for number, line in enumerate(lines, 1):
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:
            if number < len(lines):
                raise ValueError(f"{path}, line {number}: not a JSON row") from None
            logger.warning("%s: dropping a truncated last line", path)
    return [r for r in rows if up_to is None or r["iteration"] <= up_to]


def evaluation_key(name: str, step: int, episodes: int, seed: int) -> str:
    """The :data:`EVAL_FILE` key of evaluation ``name`` (``train``, ``held-out``, ``course``, ...)
    of checkpoint ``step`` on ``episodes`` episodes drawn from ``seed``."""
    return f"{name}@{step}x{episodes}s{seed}"


def entry_returns(entry: Any) -> list[float]:
    """The per-episode returns an :data:`EVAL_FILE` entry holds: the entry itself (a list), or
    its ``"return"`` (a dict that also holds an env's per-episode statistics)."""
    return entry["return"] if isinstance(entry, dict) else entry


def parse_evaluation_key(key: str) -> tuple[str, int, int, int]:
    """``(name, step, episodes, seed)`` of an :func:`evaluation_key` (``ValueError`` otherwise)."""
    match = re.fullmatch(r"(.+)@(\d+)x(\d+)s(-?\d+)", key)
    if match is None:
        raise ValueError(f"{key!r} is not an evaluation key (name@<step>x<episodes>s<seed>)")
    name, step, episodes, seed = match.groups()
    return name, int(step), int(episodes), int(seed)


class MetricsWriter:
    """Appends rows to the run's metrics files; drops the rows past iteration ``resume_from``
    (a resumed run's checkpoint; 0 on a fresh start, where no row is kept, as iterations count
    from 1) and keeps the others in ``kept``."""

    def __init__(self, run_dir: str | Path, resume_from: int, tensorboard: bool, columns: tuple[str, ...] = COLUMNS):
        self.columns = tuple(columns)
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.kept = read_history(self.run_dir, up_to=resume_from)
        self._rewrite(self.kept)
        self._tb = None
        if tensorboard:
            from tensorboardX import SummaryWriter

            # TensorBoard hides the events at steps past the checkpoint, written before the kill
            self._tb = SummaryWriter(str(self.run_dir / "tensorboard"), purge_step=resume_from + 1)

    def _rewrite(self, rows: list[dict[str, Any]]) -> None:
        """Both files anew, each written aside and renamed over the old one: a kill mid-write
        leaves the old file, never a half-written one."""
        table = io.StringIO(newline="")
        writer = csv.DictWriter(table, fieldnames=self.columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
        write_text(self.run_dir / METRICS_JSONL, "".join(json.dumps(row) + "\n" for row in rows))
        write_text(self.run_dir / METRICS_CSV, table.getvalue())

    def write(self, row: dict[str, Any]) -> None:
        """Appends one iteration's row (keys from ``columns``; missing ones stay empty)."""
        with open(self.run_dir / METRICS_JSONL, "a") as f:
            f.write(json.dumps(row) + "\n")
        with open(self.run_dir / METRICS_CSV, "a", newline="") as f:
            csv.DictWriter(f, fieldnames=self.columns, extrasaction="ignore").writerow(row)
        if self._tb is not None:
            for name, value in row.items():
                if name != "iteration" and isinstance(value, (int, float)) and math.isfinite(value):
                    self._tb.add_scalar(name, value, row["iteration"])

    def close(self) -> None:
        if self._tb is not None:
            self._tb.close()
