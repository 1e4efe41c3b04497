"""The ``dcs-<task>`` presets: the paper's Table-1 setting on each of the suite's six tasks,
validated without building anything (the quick preset's policy fits its frames); and one
quick preset's env in one compiled program: distracted frames, the perturbation drawn from the
episode's key (the same key, the same draw; episodes differ), advanced once per control step
(action repeat k: k walks per env step), held once the episode has ended, shown in the
frames, and never touching the physics."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import spread
from dm_control import suite

from iap_mjx import configs, envs, policies
from iap_mjx.configs.distraction import TASKS
from iap_mjx.configs.env import CAMERA_SETTINGS
from iap_mjx.configs.presets import ACTION_REPEAT

SUITE = {
    "cartpole-swingup": 8,
    "cheetah-run": 4,
    "ball_in_cup-catch": 4,
    "reacher-easy": 4,
    "walker-walk": 2,
    "finger-spin": 2,
}
"""The suite's six tasks and their action repeats (PlaNet/DrQ's, as the issue states them)."""


def test_every_suite_task_has_a_preset():
    assert sorted(TASKS) == sorted(SUITE)
    names = [name for name in configs.names() if name.startswith("dcs-")]
    assert sorted(names) == sorted(f"dcs-{t}{suffix}" for t in SUITE for suffix in ("", "-quick", "-cnn", "-cnn-quick"))


@pytest.mark.parametrize("task", sorted(SUITE))
def test_cnn_preset_is_the_iap_preset_with_convolutions_for_attention(task):
    """The baseline differs from ``dcs-<task>`` in its features alone: the same frames, ES, run
    and controller (an LSTM(16)); convolutions that shrink 240x320 to a 4x5 grid of 16 channels."""
    iap, cnn = configs.get(f"dcs-{task}"), configs.get(f"dcs-{task}-cnn")
    assert (cnn.env, cnn.es, cnn.run) == (iap.env, iap.es, iap.run)
    assert configs.get(f"dcs-{task}-cnn-quick").env == configs.get(f"dcs-{task}-quick").env
    action_size = envs.make(task).action_size
    baseline = policies.make(cnn.policy.kind, (240, 320, 3), action_size, **dict(cnn.policy.options))
    attention = policies.make(iap.policy.kind, (240, 320, 3), action_size, **dict(iap.policy.options))
    assert baseline.head == dataclasses.replace(attention.head, input_size=16, owner="ConvNetPolicy")
    assert baseline.body.pooled_grid == (4, 5) and baseline.body.flat_size == 4 * 5 * 16
    conv = (27 * 8 + 8) + (72 * 16 + 16) + (144 * 16 + 16)
    head = (16 + 16) * 64 + 64 + 16 * action_size + action_size
    assert policies.param_count(baseline.init(jax.random.PRNGKey(0))) == conv + (320 * 16 + 16) + head


@pytest.mark.slow
def test_cnn_quick_preset_trains_from_the_command_line(tmp_path):
    from iap_mjx import cli, es

    run_dir = tmp_path / "run"
    assert (
        cli.main(
            [
                "train",
                "dcs-cartpole-swingup-cnn-quick",
                "env.height=48",
                "env.width=64",
                "run.iterations=1",
                "--run-dir",
                str(run_dir),
                "--no-progress",
            ]
        )
        == 0
    )
    result = es.load_run(run_dir)
    assert result.config.policy.kind == "convnet" and np.isfinite(result.history[-1]["eval_return"])


def test_action_repeat_has_one_entry_per_suite_task():
    """``ACTION_REPEAT`` (the pixel presets' table) is keyed by the suite's tasks, whose one
    list is ``configs.distraction.TASKS``."""
    assert sorted(ACTION_REPEAT) == sorted(TASKS)


@pytest.mark.parametrize("task", sorted(SUITE))
def test_preset_is_the_papers_setting(task):
    config = configs.get(f"dcs-{task}")
    env_config = envs.check_spec(config.env)
    assert config.env.name == task
    assert (env_config.height, env_config.width, env_config.obs_mode) == (240, 320, "pixels")
    assert env_config.action_repeat == SUITE[task]
    dcs = env_config.distraction_config()
    assert (dcs.difficulty, dcs.dynamic, dcs.kinds) == ("medium", False, ("background", "camera", "colour"))
    options = dict(config.policy.options)
    assert config.policy.kind == "iap"
    assert (
        options["patch_size"],
        options["top_l"],
        options["kernel"],
        options["m"],
        options["r"],
        options["controller"],
    ) == (2, 10, "hybrid", 10, 5, "lstm")
    quick = configs.get(f"dcs-{task}-quick")
    assert quick.policy == config.policy and quick.env.name == config.env.name
    assert envs.check_spec(quick.env).distraction_config().kinds == dcs.kinds
    # the policy attends over the native frame's 2x2 patches: L = 19,200, as the paper
    policy = policies.make(config.policy.kind, (240, 320, 3), 1, **options)
    assert policy.layer.num_patches == 19200


DISTRACTION_SETTINGS = (
    "distraction",
    "dynamic",
    "distraction_kinds",
    "background_dir",
    "background_size",
    "background_frames",
)
"""The env settings of the distraction: the rest of a preset's settings make its undistracted env."""
STEPS = 5
"""Env steps per episode (40 control steps at action repeat 8; the preset's episodes are 10)."""
STEP_ATOL = 1e-5
"""Our env step against dm_control's from the same state (float32 against float64, no
contacts): largest gap over the 60 steps measured 5.4e-7 for qpos/qvel after the 8 control
steps, 6e-8 for the unperturbed camera's pose, 3.4e-7 for the summed reward. dm_control with
a wrong physics step (two a control step) is 0.27 off after one env step; the test requires
more than 100 x ``STEP_ATOL``."""
SAME_KEY_ATOL = 1e-6
"""Distracted against undistracted reset from the same key, every float of the physics state
(measured gap 0, bit for bit). Cartpole's reset draws its 4 coordinates as 1e-2 x N(0, 1)
from the key, so a key that the distraction consumed or changed moves the reset state by that
much: the chance that a different key lands within 1e-6 in all four is below 1e-16."""


def test_quick_preset_episode_is_distracted_deterministic_and_leaves_physics_alone():
    """dcs-cartpole-swingup-quick (action repeat 8) at 60x80, made dynamic so that walks can
    be counted; 12 distracted episodes in one program, each reset from its own key and stepped
    ``STEPS`` times under its own random actions, then an ended step and an ended step showing
    another episode's perturbation.

    The physics is checked against the undistracted episode from the same key, in two parts
    with independent references: its reset (the same preset without its distraction settings,
    reset from the same keys: every float of ``State.data``, reward and ``done`` within
    ``SAME_KEY_ATOL``), and every step of every episode (dm_control's own physics and task
    from the state before the step, under the same action: qpos, qvel, the unperturbed
    camera's pose and the reward within ``STEP_ATOL``; a dm_control step with a wrong number
    of physics steps must be further off than that, so the bound can tell). The reset's camera
    is dm_control's at the same state too.
    """
    config = configs.get("dcs-cartpole-swingup-quick")
    overrides = {**dict(config.env.overrides), "height": 60, "width": 80, "dynamic": True}
    env = envs.make(config.env.name, **overrides)
    plain = envs.make(
        config.env.name,
        **{
            **{k: v for k, v in overrides.items() if k not in DISTRACTION_SETTINGS + CAMERA_SETTINGS},
            "obs_mode": "state",
        },
    )
    repeat = env.config.action_repeat
    assert plain.config.action_repeat == repeat == SUITE[config.env.name]
    keys = jax.random.split(jax.random.PRNGKey(4), 12)
    shuffle = jnp.roll(jnp.arange(12), -1)
    actions = np.random.default_rng(0).uniform(-1, 1, (STEPS, 12, env.action_size))
    phases = jnp.asarray([0] * STEPS + [1, 2])

    @jax.jit
    def run(keys, actions):
        first = jax.vmap(env.reset)(keys)
        padded = jnp.concatenate([actions, jnp.full((2, 12, env.action_size), 0.5)])

        def step(s, inputs):
            # phase 1: the episode has ended; phase 2: ended, with another episode's perturbation
            phase, action = inputs
            other = s.replace(info={**s.info, "distraction": jax.tree.map(lambda x: x[shuffle], s.info["distraction"])})
            s = jax.tree.map(lambda a, b: jnp.where(phase == 2, b, a), s, other)
            s = s.replace(done=jnp.where(phase > 0, jnp.ones_like(s.done), s.done))
            s = jax.vmap(env.step)(s, action)
            return s, s

        states = jax.lax.scan(step, first, (phases, padded))[1]
        two = jax.vmap(lambda p: env.distraction.advance(p, 8))(first.info["distraction"])
        seen = jax.vmap(lambda d, p: env.distraction.scene(d, p)[0].cam_xpos[0])(first.data, first.info["distraction"])
        return first, states, two, seen, jax.vmap(plain.reset)(keys)

    first, states, walked, seen, plain_first = run(keys, actions)
    again = run(keys, actions)[0]
    moved, last, ended, swapped = (jax.tree.map(lambda x, i=i: x[i], states) for i in (0, STEPS - 1, STEPS, STEPS + 1))
    p0, p1 = first.info["distraction"], moved.info["distraction"]
    # determinism: the same program on the same keys gives the same draw; episodes differ
    for a, b in zip(jax.tree.leaves(p0), jax.tree.leaves(again.info["distraction"])):
        np.testing.assert_array_equal(a, b)
    sphere, colour = np.asarray(p0.camera.sphere), np.asarray(p0.colour).reshape(12, -1)
    for i in range(12):
        for j in range(i):
            assert not np.allclose(sphere[i], sphere[j]) and not np.allclose(colour[i], colour[j])

    # the reset: the undistracted env's from the same keys, every float of it
    for a, b in zip(
        jax.tree.leaves((first.data, first.reward, first.done)),
        jax.tree.leaves((plain_first.data, plain_first.reward, plain_first.done)),
    ):
        np.testing.assert_allclose(a, b, rtol=0, atol=SAME_KEY_ATOL)
    assert np.ptp(np.asarray(first.data.qpos), axis=0).min() > 1e-3  # the keys drew different states

    # every step: dm_control's physics and task from the state before it, under its action
    reference = suite.load("cartpole", "swingup", task_kwargs={"random": 0})
    physics, task = reference.physics, reference.task

    def dm_control_step(qpos, qvel, action, sub_steps=reference._n_sub_steps, control_steps=repeat):
        with physics.reset_context():
            physics.data.qpos[:], physics.data.qvel[:] = qpos, qvel
        reward = 0.0
        for _ in range(control_steps):
            task.before_step(action, physics)
            physics.step(sub_steps)
            task.after_step(physics)
            reward += task.get_reward(physics)
        data = physics.data
        return np.concatenate([data.qpos, data.qvel]), np.concatenate([data.cam_xpos[0], data.cam_xmat[0]]), reward

    before = [first] + [jax.tree.map(lambda x, t=t: x[t], states) for t in range(STEPS - 1)]
    gaps = {"state": 0.0, "camera": 0.0, "reward": 0.0}
    for t in range(STEPS):
        after = jax.tree.map(lambda x, t=t: x[t], states)
        for e in range(12):
            theirs = dm_control_step(before[t].data.qpos[e], before[t].data.qvel[e], actions[t, e])
            ours = (
                np.concatenate([after.data.qpos[e], after.data.qvel[e]]),
                np.concatenate([after.data.cam_xpos[e, 0], np.ravel(after.data.cam_xmat[e, 0])]),
                float(after.reward[e]),
            )
            for (what, gap), mine, reference_value in zip(gaps.items(), ours, theirs):
                gaps[what] = max(gap, float(np.max(np.abs(mine - reference_value))))
    assert max(gaps.values()) < STEP_ATOL, gaps
    wrong = dm_control_step(
        first.data.qpos[0], first.data.qvel[0], actions[0, 0], sub_steps=spread.wrong_sub_steps(reference._n_sub_steps)
    )[0]
    right = np.concatenate([moved.data.qpos[0], moved.data.qvel[0]])
    assert np.max(np.abs(wrong - right)) > 100 * STEP_ATOL

    # the reset camera is the physics' own (dm_control's at the same state); the perturbed pose
    # exists only in what is rendered
    for e in range(12):
        camera = dm_control_step(first.data.qpos[e], first.data.qvel[e], actions[0, e], control_steps=0)[1]
        np.testing.assert_allclose(
            np.concatenate([first.data.cam_xpos[e, 0], np.ravel(first.data.cam_xmat[e, 0])]),
            camera,
            rtol=0,
            atol=STEP_ATOL,
        )
    assert np.all(np.linalg.norm(np.asarray(seen) - np.asarray(first.data.cam_xpos[:, 0]), axis=-1) > 1e-3)

    # one env step = 8 control steps of every walk
    np.testing.assert_allclose(p1.camera.sphere, walked.camera.sphere, atol=1e-5)
    np.testing.assert_allclose(p1.colour, walked.colour, atol=1e-6)
    np.testing.assert_array_equal(p1.frame, walked.frame)
    assert not np.allclose(p1.camera.sphere, p0.camera.sphere)
    # ended: physics and perturbation hold, so the frame is the same picture: the step draws
    # the state's own (advanced) perturbation; another episode's perturbation changes it
    for a, b in zip(jax.tree.leaves(ended.info["distraction"]), jax.tree.leaves(last.info["distraction"])):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(ended.obs, last.obs, atol=1e-6)
    for i in range(12):
        assert np.abs(np.asarray(swapped.obs[i]) - np.asarray(last.obs[i])).mean() > 0.02, i
