"""The README's main command as a newcomer runs it: its output is quiet and complete.

The command is read from the README (the first fenced line that runs ``iap-mjx train``) and run
as a subprocess with a small budget appended (one ES iteration of 4 members on 8-step
episodes: the warnings this guards against come from imports, model compilation and video
writing, which any budget exercises). Its stderr must hold no warning or error line, its
stdout only the JSON summary, and the run directory everything the README promises.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / ".jax_cache"
NOISE = re.compile(r"warn|error|deprecat|failed|traceback|fork", re.IGNORECASE)
BUDGET = ["env.episode_length=8", "es.population_size=4", "run.iterations=1", "run.eval_episodes=2"]


def readme_main_command() -> list[str]:
    """The arguments of the README's ``iap-mjx train`` command (after ``iap-mjx``)."""
    for line in (ROOT / "README.md").read_text().splitlines():
        if "iap-mjx train" in line and "pip install" in line:
            return shlex.split(line.split("&& iap-mjx ", 1)[1])
    raise AssertionError("the README has no install-and-train command")


def test_the_main_command_is_the_documented_default():
    args = readme_main_command()
    assert args[0] == "train" and "--run-dir" in args
    from iap_mjx import configs

    assert args[1] in configs.names()


@pytest.mark.slow
def test_main_command_prints_no_warnings_and_leaves_every_artifact(tmp_path):
    args = readme_main_command()
    env = dict(os.environ, IAP_MJX_CACHE_DIR=str(CACHE))
    env.pop("MUJOCO_GL", None)  # as on a newcomer's machine (the tests' conftest sets it)
    command = [*args[:2], *BUDGET, *args[2:]]  # overrides follow the preset's name
    done = subprocess.run([sys.executable, "-m", "iap_mjx.cli", *command], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=1500)
    assert done.returncode == 0, done.stderr
    noisy = [line for line in done.stderr.splitlines() if NOISE.search(line)]
    assert not noisy, "\n".join(noisy)
    (line,) = done.stdout.splitlines()
    summary = json.loads(line)
    run_dir = tmp_path / args[args.index("--run-dir") + 1]
    for name in ("config.json", "metrics.csv", "metrics.jsonl", "reward_curve.png", "episode.mp4"):
        assert (run_dir / name).stat().st_size > 0, name
    assert sorted(Path(path).name for path in summary["artifacts"]) == ["episode.mp4", "reward_curve.png"]
    assert (run_dir / "checkpoints").is_dir() and (run_dir / "tensorboard").is_dir()
