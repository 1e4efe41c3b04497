"""Every pixel preset builds its env and policy (no compile) and its policy is the one named;
every task's ``<task>-pixels`` preset's ES iteration traces end to end (cheetah-run's trains
through the README's command in ``test_first_run``).

The other tasks' iterations are traced, not compiled: compiling one costs about a minute of
the CI's budget, and what a preset adds to its parts (the env's frames into the IAP layer and
the LSTM, their actions back into the env, the ES update over their parameters) is wired at
trace time. Each task's physics runs against dm_control in ``test_envs_parity``, its frames
against MuJoCo's renderer in ``test_distraction_images``, and its ``dcs-`` preset trains in
Table 1."""

import dataclasses

import jax
import numpy as np
import pytest

from iap_mjx import configs, envs, policies
from iap_mjx.configs.presets import ACTION_REPEAT
from iap_mjx.es import components, iteration
from iap_mjx.policies.base import param_count

PIXEL_PRESETS = [name for name in configs.names() if "pixels" in name]


def test_every_dm_control_task_has_a_pixel_preset():
    from iap_mjx.envs.registry import _task_classes

    dm_control_tasks = {name for name, cls in _task_classes().items() if cls.domain is not None}
    assert dm_control_tasks >= {
        "cheetah-run",
        "walker-walk",
        "cartpole-swingup",
        "ball_in_cup-catch",
        "reacher-easy",
        "finger-spin",
    }
    assert {f"{task}-pixels" for task in dm_control_tasks} <= set(PIXEL_PRESETS)


@pytest.mark.parametrize("name", PIXEL_PRESETS)
def test_pixel_preset_builds_env_and_policy(name):
    config = configs.get(name)
    env = envs.make_spec(config.env)
    assert env.observation_shape == (100, 100, 3)
    assert env.config.action_repeat == ACTION_REPEAT[config.env.name]
    policy = policies.make(config.policy.kind, env.observation_shape, env.action_size, **dict(config.policy.options))
    params = jax.eval_shape(policy.init, jax.random.PRNGKey(0))
    assert config.policy.kind == "iap"
    assert policy.layer.num_patches == 625 and policy.attention.top_l == 10
    # W_Q, W_K (48 x 4 each) and a 16-unit LSTM on 10 centres, read out to the actions.
    lstm = (20 + 16) * 4 * 16 + 4 * 16 + 16 * env.action_size + env.action_size
    assert param_count(params) == 2 * 48 * 4 + lstm
    variant = name.removeprefix(f"{config.env.name}-pixels").lstrip("-")
    expected = variant.split("-")[0] if variant in configs.presets.FIG6_KERNELS else "hybrid"
    assert policy.attention.kernel == expected


def test_paper_feature_settings():
    for suffix, (m, r) in {"hybrid-3-2": (3, 2), "hybrid-6-3": (6, 3), "hybrid-16-8": (16, 8)}.items():
        options = dict(configs.get(f"cheetah-run-pixels-{suffix}").policy.options)
        assert (options["m"], options["r"]) == (m, r)
    options = dict(configs.get("cheetah-run-pixels").policy.options)
    assert (options["kernel"], options["m"], options["r"]) == ("hybrid", 10, 5)
    assert dict(configs.get("cheetah-run-pixels-brute").policy.options)["row_normalize"] is True


def test_the_first_run_preset_is_cheetah_run_pixels_on_a_smaller_budget():
    """``cheetah-run-pixels-quick`` (the README's main job) differs from ``cheetah-run-pixels``
    only in the ES population and step size and the loop's budget: its env, camera and policy
    are the preset's, so the main command's test (``test_first_run``, one iteration through
    the CLI) is cheetah-run-pixels' one-iteration test."""
    quick, full = configs.get("cheetah-run-pixels-quick"), configs.get("cheetah-run-pixels")
    assert (quick.env, quick.policy) == (full.env, full.policy)
    assert (
        dataclasses.replace(quick.es, population_size=full.es.population_size, learning_rate=full.es.learning_rate)
        == full.es
    )


def _shrunk(task: str):
    """The task's preset as named, shrunk only in its budget (2 frames per episode, 4 members,
    one iteration)."""
    config = configs.apply_overrides(
        configs.get(f"{task}-pixels"),
        [
            "env.episode_length=2",
            "es.population_size=4",
            "run.iterations=1",
            "run.eval_episodes=2",
            "run.checkpoint_every=0",
            "run.tensorboard=false",
        ],
    )
    start = configs.get(f"{task}-pixels")
    assert dataclasses.replace(config, env=start.env, es=start.es, run=start.run) == start
    return config


@pytest.mark.parametrize("task", sorted(set(ACTION_REPEAT) - {"cheetah-run"}))
def test_task_pixel_preset_iteration_traces(task):
    """Every task's preset but cheetah-run's, shrunk only in its budget: one ES iteration traces
    (``jax.eval_shape``, no compile) to a state shaped as the one it started from and a ``(1,)``
    row per metric, over as many parameters as the policy has."""
    parts = components.build(_shrunk(task))
    state = components.init_state(parts)
    new_state, metrics = jax.eval_shape(iteration.make_train_call(parts, 1), state)
    assert jax.tree_util.tree_structure(new_state) == jax.tree_util.tree_structure(state)
    for before, after in zip(jax.tree_util.tree_leaves(state), jax.tree_util.tree_leaves(new_state)):
        assert (after.shape, after.dtype) == (before.shape, before.dtype)
    for name in ("return_mean", "return_max", "eval_return", "nan_episodes", "params_norm"):
        assert metrics[name].shape == (1,), name
    assert metrics["return_mean"].dtype == np.float32
    policy = parts.policy
    assert param_count(policy.init(jax.random.PRNGKey(0))) == parts.num_dims
