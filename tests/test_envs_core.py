"""Registry, config validation, action checks, done/bad-state handling of the env ports."""

from __future__ import annotations

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from iap_mjx import envs

TASKS = ("ball_in_cup-catch", "cartpole-swingup", "cheetah-run", "finger-spin", "reacher-easy", "walker-walk")


def test_names_lists_the_six_tasks():
    assert set(TASKS) <= set(envs.names())


@pytest.mark.parametrize("name", TASKS)
def test_model_is_dm_controls_own_and_builds_without_warnings(name):
    """Every array of the compiled model equals dm_control's (cheetah's total mass is set
    after compiling, not by the deprecated compiler attribute), apart from our contact-slot
    numeric (and the name map that lists it); the solver settings are options, not arrays.
    Building the env warns about nothing."""
    import warnings

    from dm_control import suite

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = envs.make(name)
    domain, task = name.split("-")
    reference_env = suite.load(domain, task)
    filtered = ()
    if name == "finger-spin":
        from iap_mjx.envs.finger import _NEVER_TOUCHING

        # Its initialize_episode edits the model the same way at every reset (hinge damping,
        # two hidden sites), and we drop the collision flags of geoms that cannot touch
        # (tests/test_envs_finger.py), which also prunes MuJoCo's collision BVH.
        reference_env.reset()
        filtered = ("contype", "conaffinity", "bvh")
        theirs = reference_env.physics.model._model
        expected = theirs.geom_contype.copy()
        expected[[mujoco.mj_name2id(theirs, mujoco.mjtObj.mjOBJ_GEOM, g) for g in _NEVER_TOUCHING]] = 0
        np.testing.assert_array_equal(env.mj_model.geom_contype, expected)
        np.testing.assert_array_equal(env.mj_model.geom_conaffinity, expected)
    reference = reference_env.physics.model._model
    ours = env.mj_model
    compared = 0
    for field in dir(reference):
        theirs = getattr(reference, field, None)
        ours_only = "numeric" in field or field == "names_map" or any(word in field for word in filtered)
        if field.startswith("_") or ours_only or not isinstance(theirs, np.ndarray):
            continue
        np.testing.assert_array_equal(getattr(ours, field), theirs, err_msg=field)
        compared += 1
    assert compared > 100
    np.testing.assert_array_equal(ours.body_mass, reference.body_mass)


def test_unknown_name_lists_valid_ones():
    with pytest.raises(ValueError) as error:
        envs.make("cheetah-walk")
    for name in envs.names():
        assert name in str(error.value)


@pytest.mark.parametrize(
    "overrides",
    [
        dict(action_repeat=0),
        dict(solver_iterations=0),
        dict(episode_length=0),
        dict(obs_mode="rgb"),
        dict(max_abs_state=-1.0),
        dict(max_contacts=0),
        dict(max_contacts="some"),
    ],
)
def test_bad_config_field_is_named(overrides):
    (field,) = overrides
    with pytest.raises(ValueError, match=field):
        envs.make("cheetah-run", **overrides)


def test_unknown_setting_lists_valid_ones():
    with pytest.raises(ValueError, match="heigth") as error:
        envs.check("cheetah-run", heigth=64)
    assert "height" in str(error.value) and "action_repeat" in str(error.value)
    with pytest.raises(ValueError, match="heigth"):
        envs.make("cheetah-run", heigth=64)
    assert envs.check("cheetah-run", obs_mode="pixels", height=64).height == 64


# The done/bad-state machinery is shared by all tasks (iap_mjx/envs/dmc.py); it is tested on
# reacher-easy, the cheapest to compile and run.
@pytest.fixture(scope="module")
def reacher():
    return envs.make("reacher-easy", episode_length=5)


@pytest.fixture(scope="module")
def reacher_batch(reacher):
    """Four reachers reset from four keys, and a jitted batched step."""
    states = jax.jit(jax.vmap(reacher.reset))(jax.random.split(jax.random.key(0), 4))
    return states, jax.jit(jax.vmap(reacher.step))


def test_config_and_models_are_exposed():
    cheetah = envs.make("cheetah-run", solver_iterations=3)
    assert cheetah.mj_model.opt.iterations == 3
    assert cheetah.mjx_model.opt.iterations == 3
    assert cheetah.mjx_model.nu == cheetah.action_size == 6
    assert cheetah.observation_shape == (17,)
    assert envs.make("cheetah-run", action_repeat=3).episode_length == 334


@pytest.mark.parametrize("name", envs.names())
def test_episode_length_is_read_without_building_the_env(name):
    """``envs.episode_length`` (the figures' frame counts) agrees with the built env's, for
    every task (``quadruped-flat`` and ``quadruped-turn`` last 500 control steps, the others 1000), with an
    action repeat where the task takes one and with a set length; the dm_control tasks' default
    is dm_control's own step limit."""
    repeats = [{}] if name.startswith("quadruped") else [{}, {"action_repeat": 3}]
    for overrides in (*repeats, {"episode_length": 7}):
        assert envs.episode_length(name, **overrides) == envs.make(name, **overrides).episode_length
    if not name.startswith("quadruped"):
        from dm_control import suite

        domain, task = name.split("-")
        assert envs.episode_length(name) == suite.load(domain, task)._step_limit


def test_episode_length_of_an_unknown_env_names_the_valid_ones():
    with pytest.raises(ValueError, match="Unknown env 'cheetah-walk'; valid names: ball_in_cup-catch"):
        envs.episode_length("cheetah-walk")


@pytest.mark.parametrize(
    "action, error",
    [
        (jnp.zeros(3), ValueError),
        (jnp.zeros((1, 2)), ValueError),
        (jnp.zeros(2, jnp.int32), TypeError),
    ],
)
def test_wrong_action_is_a_trace_time_error(reacher, reacher_batch, action, error):
    state = jax.tree.map(lambda x: x[0], reacher_batch[0])
    with pytest.raises(error, match="action"):
        jax.eval_shape(reacher.step, state, action)


def test_bad_state_ends_only_that_env(reacher_batch):
    states, step = reacher_batch
    actions = jnp.zeros((4, 2)).at[1].set(jnp.nan)  # env 1 gets a NaN action
    qvel = states.data.qvel.at[2, 0].set(1e9)  # env 2 starts beyond max_abs_state...
    clean = step(states, jnp.zeros((4, 2)))
    states = states.replace(data=states.data.replace(qvel=qvel))
    # ...which is only looked at after a step, so it is ended by the first step too.
    after = step(states, actions)
    assert np.all(np.isfinite(np.asarray(after.reward)))
    assert np.all(np.isfinite(np.asarray(after.obs)))
    np.testing.assert_array_equal(after.done, [0, 1, 1, 0])
    np.testing.assert_array_equal(after.metrics["nan_terminations"], [0, 1, 1, 0])
    np.testing.assert_array_equal(after.reward[np.array([1, 2])], [0, 0])
    # The good envs are exactly what they are when stepped without the bad ones.
    good = np.array([0, 3])
    np.testing.assert_array_equal(after.obs[good], clean.obs[good])
    np.testing.assert_array_equal(after.reward[good], clean.reward[good])
    # A bad env keeps its last good physics state, and stays done.
    np.testing.assert_array_equal(after.data.qpos[1], states.data.qpos[1])
    again = step(after, jnp.zeros((4, 2)))
    np.testing.assert_array_equal(again.done[np.array([1, 2])], [1, 1])
    np.testing.assert_array_equal(again.data.qpos[1], states.data.qpos[1])
    np.testing.assert_array_equal(again.metrics["nan_terminations"], [0, 1, 1, 0])


def test_time_limit_sets_done_and_freezes(reacher_batch):
    states, step = reacher_batch
    action = jnp.full((4, 2), 0.5)
    dones = []
    for _ in range(7):
        before = states
        states = step(states, action)
        dones.append(np.asarray(states.done))
    np.testing.assert_array_equal(np.array(dones)[:, 0], [0, 0, 0, 0, 1, 1, 1])
    np.testing.assert_array_equal(states.info["steps"], [5, 5, 5, 5])
    np.testing.assert_array_equal(states.reward, np.zeros(4))
    np.testing.assert_array_equal(states.data.qpos, before.data.qpos)
    np.testing.assert_array_equal(states.metrics["nan_terminations"], np.zeros(4))


@pytest.mark.slow
def test_action_repeat_holds_the_action_and_sums_rewards():
    single = envs.make("reacher-easy")
    repeated = envs.make("reacher-easy", action_repeat=2)
    assert repeated.episode_length == 500
    qpos, qvel = jnp.array([0.3, -1.2]), jnp.array([0.5, 0.1])
    # Target on the finger, so the rewards of both control steps are 1, not 0.
    reset_to = jax.jit(single.reset_to)  # compiled once: eager MJX dispatches hundreds of ops
    origin_minus_finger = reset_to(qpos, qvel, target=jnp.zeros(2)).obs[2:4]
    start = reset_to(qpos, qvel, target=-origin_minus_finger)
    action = jnp.array([1.0, -0.4])
    step = jax.jit(single.step)
    once = step(start, action)
    twice = step(once, action)
    held = jax.jit(repeated.step)(start, action)
    np.testing.assert_allclose(held.data.qpos, twice.data.qpos, rtol=1e-6, atol=1e-6)
    assert float(once.reward) == float(twice.reward) == 1.0
    np.testing.assert_allclose(held.reward, once.reward + twice.reward, atol=1e-6)
    np.testing.assert_array_equal(held.info["steps"], 1)


def test_pixel_modes_go_through_the_camera_wrapper():
    from iap_mjx.envs.pixels import PixelEnv

    env = envs.make("cartpole-swingup", obs_mode="pixels", height=16, width=24, frame_stack=2)
    assert isinstance(env, PixelEnv)
    assert env.config.obs_mode == "pixels" and env.frame_stack == 2
    # the wrapped env is cartpole's state env: its state observation is the plain env's
    plain = envs.make("cartpole-swingup")
    state = jax.jit(plain.reset)(jax.random.PRNGKey(0))
    assert type(env.env) is type(plain) and env.env.observation_shape == (5,)
    np.testing.assert_array_equal(env.env.state_observation(state.data), state.obs)


@pytest.mark.parametrize("n_steps", [0, 1, 5])
def test_settle_is_forward_then_n_steps_then_forward(n_steps):
    """Cheetah's settling (``_settle``, one loop that discards the last round's dynamics)
    against native MuJoCo from the same randomised ``qpos``: ``mj_forward``, ``n_steps`` x
    ``mj_step``, ``mj_forward``. The state after the steps and the position stage computed at
    it (body positions, sensors) must agree; a round too many or too few moves the falling
    cheetah by ~``qvel * dt`` (>= 1e-3 here), far above float32's error."""
    env = envs.make("cheetah-run")
    model = env.mj_model
    rng = np.random.default_rng(0)
    lower, upper = model.jnt_range.T
    qpos = np.where(model.jnt_limited == 1, rng.uniform(lower, upper), model.qpos0).astype(np.float32)
    start = mjx.make_data(model).replace(qpos=jnp.asarray(qpos))
    ours = jax.jit(lambda d: env._settle(d, n_steps))(start)

    def native_settle(steps: int) -> mujoco.MjData:
        native = mujoco.MjData(model)
        native.qpos[:] = qpos
        mujoco.mj_forward(model, native)
        for _ in range(steps):
            mujoco.mj_step(model, native)
        mujoco.mj_forward(model, native)
        return native

    native = native_settle(n_steps)
    np.testing.assert_allclose(ours.qpos, native.qpos, atol=1e-4)
    np.testing.assert_allclose(ours.qvel, native.qvel, atol=1e-4)
    np.testing.assert_allclose(ours.xpos, native.xpos, atol=1e-4)
    np.testing.assert_allclose(ours.sensordata, native.sensordata, atol=1e-4)
    # the bound's power: a round too many or too few is outside it
    for wrong in {n_steps + 1, max(n_steps - 1, 0)} - {n_steps}:
        other = native_settle(wrong)
        gap = max(np.max(np.abs(ours.qpos - other.qpos)), np.max(np.abs(ours.qvel - other.qvel)))
        assert gap > 1e-3, (wrong, gap)


def test_importing_and_building_every_env_prints_nothing():
    """The README's Python example as a user runs it, in a fresh interpreter on a headless
    machine with neither ``MUJOCO_GL`` nor ``DISPLAY`` set: importing the package and building
    every env (state and pixels) writes nothing to stdout or stderr (dm_control's OpenGL probe
    warned ``GLFWError ... DISPLAY environment variable is missing`` before its import was
    made quiet)."""
    script = (
        "from iap_mjx import envs\n"
        "for name in envs.names():\n"
        "    envs.make(name)\n"
        "envs.make('cartpole-swingup', obs_mode='pixels', height=24, width=32)\n"
    )
    environment = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "PYOPENGL_PLATFORM")}
    done = subprocess.run([sys.executable, "-c", script], env=environment, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "" and done.stderr == "", done.stdout + done.stderr


def test_a_task_class_refuses_another_tasks_config():
    """Built directly (not through the registry), a task still takes only its own config class."""
    from iap_mjx.configs.env import QuadrupedConfig
    from iap_mjx.envs.cheetah import CheetahRun

    with pytest.raises(ValueError, match="cheetah-run takes a EnvConfig, got a QuadrupedConfig"):
        CheetahRun(QuadrupedConfig())
