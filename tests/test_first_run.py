"""The README's main command as a newcomer runs it, then ``iap-mjx eval`` on what it left.

The command is read from the README (the first line that installs and runs ``iap-mjx train``)
and run as a subprocess with a small budget after the preset's name: two ES iterations of 8
members on 60-step episodes, a checkpoint after each. The warnings this guards against come
from imports, model compilation and video writing, which any budget exercises. Its stderr must
hold no warning or error line, its stdout only the JSON summary, and the run directory
everything the README promises; ``iap-mjx eval`` then restores the last checkpoint.

The budget is the quickstart notebook's (``tests/test_notebook.py`` runs after this test, see
``conftest.py``): the same programs, so the notebook loads them from the compilation cache.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import report  # noqa: E402  (benchmarks/report.py: the README's command, as first_run.py reads it)

from iap_mjx import configs  # noqa: E402

CACHE = ROOT / ".jax_cache"
NOISE = re.compile(r"warn|error|deprecat|failed|traceback|fork", re.IGNORECASE)
EPISODE_STEPS = 60
BUDGET = [
    f"env.episode_length={EPISODE_STEPS}",
    "es.population_size=8",
    "run.iterations=2",
    "run.eval_episodes=2",
    "run.checkpoint_every=1",
]


def test_the_main_command_is_the_documented_default():
    args = report.readme_main_command()
    assert args[0] == "train" and "--run-dir" in args
    assert args[1] in configs.names()


def _newcomer_env() -> dict[str, str]:
    """The environment the README's command runs in here: a newcomer's, but the tests' cache."""
    env = dict(os.environ, IAP_MJX_CACHE_DIR=str(CACHE))
    env.pop("MUJOCO_GL", None)  # as on a newcomer's machine (the tests' conftest sets it)
    env.pop("JAX_USE_SHARDY_PARTITIONER", None)  # JAX's default partitioner (conftest sets GSPMD)
    return env


def _cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "iap_mjx.cli", *args], cwd=cwd, env=_newcomer_env(), capture_output=True, text=True
    )


def test_the_main_command_runs_under_shardy():
    """The rest of the suite partitions with GSPMD (``conftest.py``); the README's command runs
    with JAX's default, Shardy, as a user's does."""
    code = "import jax; print(jax.config.jax_use_shardy_partitioner)"
    done = subprocess.run([sys.executable, "-c", code], env=_newcomer_env(), capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "True"


@pytest.mark.slow
def test_main_command_is_quiet_leaves_every_artifact_and_evaluates(tmp_path):
    args = report.readme_main_command()
    command = [*args[:2], *BUDGET, *args[2:]]  # overrides follow the preset's name
    done = _cli(command, tmp_path)
    assert done.returncode == 0, done.stderr
    noisy = [line for line in done.stderr.splitlines() if NOISE.search(line)]
    assert not noisy, "\n".join(noisy)

    (line,) = done.stdout.splitlines()  # stdout is the summary alone
    summary = json.loads(line)
    run_dir = tmp_path / args[args.index("--run-dir") + 1]
    assert summary["iterations"] == 2 and Path(summary["run_dir"]) == run_dir.relative_to(tmp_path)
    for name in ("config.json", "metrics.csv", "metrics.jsonl", "reward_curve.png", "episode.mp4"):
        assert (run_dir / name).stat().st_size > 0, name
    assert sorted(Path(path).name for path in summary["artifacts"]) == ["episode.mp4", "reward_curve.png"]
    assert (run_dir / "tensorboard").is_dir()
    assert sorted(p.name for p in (run_dir / "checkpoints").iterdir()) == ["1", "2"]
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [row["iteration"] for row in rows] == [1, 2]
    expected = configs.apply_overrides(configs.get(args[1]), BUDGET)
    written = json.loads((run_dir / "config.json").read_text())
    assert written["es"]["population_size"] == 8
    assert written["env"]["overrides"]["episode_length"] == EPISODE_STEPS
    assert configs.TrainConfig.from_dict(written) == expected

    evaluated = _cli(["eval", str(run_dir), "--episodes", "3"], tmp_path)
    assert evaluated.returncode == 0, evaluated.stderr
    report_line = json.loads(evaluated.stdout.strip().splitlines()[-1])
    assert report_line["episodes"] == 3 and len(report_line["returns"]) == 3
    # cheetah-run rewards are in [0, 1] per control step
    assert all(0.0 <= r <= EPISODE_STEPS for r in report_line["returns"])
    assert len(set(report_line["returns"])) == 3  # three episodes, three different starts
