"""The ``quadruped-walls-*`` presets: each is the hierarchy it names on the course's camera, and
trains one ES iteration shrunk only in its budget (5-step episodes, 4 members), one of them
through the command line; the course statistics and the parameter count reach the metrics."""

from __future__ import annotations

import csv
import dataclasses
import json

import course
import numpy as np
import pytest

from iap_mjx import cli, configs, envs, policies
from iap_mjx.es import train

PRESETS = ("quadruped-walls-iap", "quadruped-walls-cnn", "quadruped-walls-blind")
SHRINK = course.SHRINK
COURSE_COLUMNS = course.course_columns(("walls_passed", "fell_off", "wall_contacts", "distance"))


def test_presets_are_the_hierarchies_they_name():
    seen = {}
    for name in PRESETS:
        config = configs.get(name)
        env_config = envs.check_spec(config.env)
        assert (config.env.name, env_config.obs_mode, env_config.height, env_config.width) == (
            "quadruped-walls",
            "pixels+state",
            24,
            32,
        )
        assert config.policy.kind == "hierarchical" and not config.es.normalize_observations
        policy = policies.make(
            "hierarchical", {"pixels": (24, 32, 3), "state": (17,)}, 12, **dict(config.policy.options)
        )
        seen[name] = policy
        assert policy.duration_range == (10, 50) and policy.latent_size == 4 and policy.low_level_init is None
    assert seen["quadruped-walls-iap"].high.attention.kernel == "relu"
    assert not seen["quadruped-walls-iap"].blind and seen["quadruped-walls-blind"].blind
    assert seen["quadruped-walls-blind"].high == seen["quadruped-walls-iap"].high  # the same high level, eyes shut
    assert type(seen["quadruped-walls-cnn"].high).__name__ == "ConvNet"
    # the same ES and budget for the three, so that their curves compare
    assert len({(configs.get(name).es, configs.get(name).run) for name in PRESETS}) == 1
    # Table 2's settings reach the IAP high level from the command line
    table2 = configs.apply_overrides(configs.get("quadruped-walls-iap"), ["policy.patch_size=1", "policy.stride=1"])
    policy = policies.make("hierarchical", {"pixels": (24, 32, 3), "state": (17,)}, 12, **dict(table2.policy.options))
    assert policy.layer.num_patches == 24 * 32


def _shrunk(name: str) -> configs.TrainConfig:
    config = configs.apply_overrides(configs.get(name), SHRINK)
    start = configs.get(name)
    assert dataclasses.replace(config, env=start.env, es=start.es, run=start.run) == start
    return config


@pytest.mark.slow
@pytest.mark.parametrize("name", ["quadruped-walls-cnn", "quadruped-walls-blind"])
def test_preset_trains_one_iteration(name, tmp_path):
    result = train(_shrunk(name), run_dir=tmp_path, progress=False)
    (row,) = result.history
    assert np.isfinite(row["return_mean"]) and np.isfinite(row["eval_return"]) and row["nan_episodes"] == 0
    for column in COURSE_COLUMNS:
        assert np.isfinite(row[column]), column
    assert 0 <= row["walls_passed_mean"] <= 3 and row["parameters"] == (7269 if name.endswith("cnn") else 873)
    with open(tmp_path / "metrics.csv") as f:
        (stored,) = list(csv.DictReader(f))
    assert float(stored["eval_distance"]) == pytest.approx(row["eval_distance"]) and stored["parameters"] == str(
        row["parameters"]
    )


@pytest.mark.slow
def test_iap_preset_trains_from_the_command_line(tmp_path, capsys):
    """``iap-mjx train quadruped-walls-iap ...``: one iteration, its metrics, the episode video
    with the high level's patches outlined, and ``iap-mjx eval`` with the course statistics."""
    run_dir = tmp_path / "run"
    assert cli.main(["train", "quadruped-walls-iap", *SHRINK, "--run-dir", str(run_dir), "--no-progress"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["iterations"] == 1 and np.isfinite(summary["eval_return"])
    with open(run_dir / "metrics.csv") as f:
        reader = csv.DictReader(f)
        (row,) = list(reader)
    assert set(COURSE_COLUMNS) <= set(reader.fieldnames) and row["parameters"] == "873"
    course.check_scene_video(run_dir / "episode.mp4")  # the course from outside, the robot's view inset
    # iap-mjx eval reports the course statistics of fresh episodes too
    assert cli.main(["eval", str(run_dir), "--episodes", "2"]) == 0
    evaluated = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert evaluated["episodes"] == 2 and 0 <= evaluated["walls_passed_mean"] <= 3
    assert {f"{name}_mean" for name in ("fell_off", "wall_contacts", "distance")} <= set(evaluated)
