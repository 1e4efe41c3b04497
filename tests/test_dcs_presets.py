"""The ``dcs-<task>`` presets: the paper's Table-1 setting on every suite task, validated without
building anything; one quick preset runs an episode whose frames are distracted and whose
selected patches are recorded (what ``iap-mjx video`` draws)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from iap_mjx import configs, envs, policies
from iap_mjx.configs import dcs_presets
from iap_mjx.viz import video

DCS = [name for name in configs.names() if name.startswith("dcs-") and not name.endswith("-quick")]


def test_every_suite_task_has_a_preset():
    tasks = [t for t in dcs_presets.ACTION_REPEAT if t in envs.names()]
    assert sorted(DCS) == sorted(f"dcs-{t}" for t in tasks)
    assert len(tasks) >= 5


@pytest.mark.parametrize("name", DCS)
def test_preset_is_the_papers_setting(name):
    config = configs.get(name)
    task = name.removeprefix("dcs-")
    env_config = envs.check(config.env.name, **dict(config.env.overrides))
    assert (env_config.height, env_config.width, env_config.obs_mode) == (240, 320, "pixels")
    assert env_config.action_repeat == {"cartpole-swingup": 8, "cheetah-run": 4, "ball_in_cup-catch": 4,
                                        "reacher-easy": 4, "walker-walk": 2, "finger-spin": 2}[task]
    dcs = env_config.distraction_config()
    assert (dcs.difficulty, dcs.dynamic, dcs.kinds) == ("medium", False, ("background", "camera", "colour"))
    options = dict(config.policy.options)
    assert config.policy.kind == "iap"
    assert (options["patch_size"], options["top_l"], options["kernel"], options["m"], options["r"],
            options["controller"]) == (2, 10, "hybrid", 10, 5, "lstm")
    quick = configs.get(f"{name}-quick")
    assert quick.policy == config.policy and quick.env.name == config.env.name


def test_quick_preset_runs_distracted_frames_with_selected_patches():
    config = configs.get("dcs-reacher-easy-quick")
    overrides = dict(config.env.overrides)
    env = envs.make(config.env.name, **overrides)
    plain = envs.make(config.env.name, **{k: v for k, v in overrides.items() if k != "distraction"})
    policy = policies.make(config.policy.kind, env.observation_shape, env.action_size,
                           **dict(config.policy.options))
    assert env.observation_shape == (240, 320, 3) and policy.layer.num_patches == 120 * 160
    params = policy.init(jax.random.PRNGKey(0))
    record = video.run_episode(env, policy, params, jax.random.PRNGKey(1), steps=2)
    assert record["frames"].shape == (2, 240, 320, 3) and record["indices"].shape == (2, 10)
    undistracted = np.asarray(jax.jit(plain.reset)(jax.random.split(jax.random.PRNGKey(1))[0]).obs)
    assert np.abs(record["frames"][0] - undistracted).mean() > 0.05
