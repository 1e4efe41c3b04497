"""The ``quadruped-gates-*`` presets: the hierarchy over the corridor's depth camera (IAP, and the
blind control, the IAP preset with its eyes shut); the IAP one trains one ES iteration through
the command line, shrunk only in its budget (5-step episodes, 4 members), and the corridor's
statistics reach the metrics."""

from __future__ import annotations

import csv
import json

import course
import jax
import numpy as np
import pytest

from iap_mjx import cli, configs, envs, policies

PRESETS = ("quadruped-gates-iap", "quadruped-gates-blind")
SHRINK = course.SHRINK
COURSE_COLUMNS = course.course_columns(("gates_passed", "collisions", "left_corridor", "fell_over", "distance"))
OBSERVATION = {"pixels": (24, 32, 1), "state": (17,)}


def test_presets_are_the_hierarchy_over_depth():
    seen = {}
    for name in PRESETS:
        config = configs.get(name)
        env_config = envs.check_spec(config.env)
        assert (config.env.name, env_config.obs_mode, env_config.height, env_config.width) == (
            "quadruped-gates",
            "depth+state",
            24,
            32,
        )
        assert config.policy.kind == "hierarchical"
        seen[name] = policies.make("hierarchical", OBSERVATION, 12, **dict(config.policy.options))
    iap, blind = seen["quadruped-gates-iap"], seen["quadruped-gates-blind"]
    assert iap.high.attention.kernel == "relu" and iap.high.image_shape == (24, 32, 1)
    assert not iap.blind and blind.blind and blind.high == iap.high  # the same high level, eyes shut
    assert iap.duration_range == (10, 50) and iap.latent_size == 4
    # 617 parameters: the walls course's 873 less W_Q and W_K's rows for two of three channels
    # (4x4 patches of 1 channel, not 3: 2 x 32 x 4 = 256 fewer)
    for policy in (iap, blind):
        assert sum(policy.level_param_counts(policy.init(jax.random.PRNGKey(0))).values()) == 617
    # the walls presets' ES and budget, so that the courses compare
    walls = configs.get("quadruped-walls-iap")
    for name in PRESETS:
        assert (configs.get(name).es, configs.get(name).run) == (walls.es, walls.run)
    assert configs.get("quadruped-gates-iap").policy == walls.policy  # the walls course's IAP hierarchy


def test_blind_preset_is_the_iap_preset_with_its_eyes_shut():
    """The blind control differs from ``quadruped-gates-iap`` in the ``blind`` option alone, so
    that it trains the program ``test_iap_preset_trains_from_the_command_line`` compiles with the
    depth zeroed: ``blind`` itself trains on the walls course
    (``test_quadruped_presets``), and training it again here would cost a minute of CI's budget."""
    iap, blind = configs.get("quadruped-gates-iap"), configs.get("quadruped-gates-blind")
    options = dict(blind.policy.options)
    assert options.pop("blind") is True and "blind" not in dict(iap.policy.options)
    assert options == dict(iap.policy.options) and blind.policy.kind == iap.policy.kind
    assert (blind.env, blind.es, blind.run) == (iap.env, iap.es, iap.run)


@pytest.mark.slow
def test_iap_preset_trains_from_the_command_line(tmp_path, capsys):
    """``iap-mjx train quadruped-gates-iap ...``: one iteration, the corridor's columns in
    ``metrics.csv``, and the episode video of the depth frames with the patches outlined."""
    run_dir = tmp_path / "run"
    assert cli.main(["train", "quadruped-gates-iap", *SHRINK, "--run-dir", str(run_dir), "--no-progress"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["iterations"] == 1 and np.isfinite(summary["eval_return"])
    with open(run_dir / "metrics.csv") as f:
        reader = csv.DictReader(f)
        (row,) = list(reader)
    assert set(COURSE_COLUMNS) <= set(reader.fieldnames)
    assert int(row["parameters"]) == 617  # derived above
    course.check_scene_video(run_dir / "episode.mp4")  # the course from outside, the robot's view inset
