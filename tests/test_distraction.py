"""The distraction layer: settings fail early and clearly, samples cover and stay inside
their intervals, dynamic walks keep to their boxes and step caps, the background video
ping-pongs as the reference's loop does, the same key gives the same perturbation, and the
layer runs inside the pixel env (k walks per env step at action repeat k, physics untouched).

Walks and draws are exercised on a small synthetic set of background videos (the loader
itself is tested in ``test_backgrounds.py``)."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from iap_mjx import envs
from iap_mjx.envs import backgrounds, distraction
from iap_mjx.envs.pixels import with_pixels
from iap_mjx.envs.registry import _task_classes

SIZE = (24, 32)
LENGTHS = (5, 3, 1)


@pytest.fixture(scope="module")
def videos():
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (len(LENGTHS), max(LENGTHS), 16, 16, 3), dtype=np.uint8)
    return backgrounds.BackgroundVideos(frames=frames, lengths=np.asarray(LENGTHS, np.int32),
                                        names=("a", "b", "c"), source="test")


def _layer(name, videos, dynamic, difficulty="medium", action_repeat=2):
    base = _task_classes()[name](envs.EnvConfig(action_repeat=action_repeat))
    config = distraction.DistractionConfig(difficulty=difficulty, dynamic=dynamic)
    return with_pixels(base, height=SIZE[0], width=SIZE[1], distraction=config, videos=videos)


@pytest.fixture(scope="module")
def reset_data():
    """A dm_control state per task (the camera draw reads the unperturbed camera from it)."""
    from mujoco import mjx

    from iap_mjx.viz import render_compare

    def get(env):
        (model, data), = render_compare.suite_states(*env.env.name.split("-"), n_states=1, seed=0)
        return mjx.put_data(model, data)
    return get


def test_bad_settings_fail_before_compiling_naming_the_setting(tmp_path):
    with pytest.raises(ValueError, match="distraction = 'medum'.*easy, medium, hard"):
        envs.check("cartpole-swingup", obs_mode="pixels", distraction="medum")
    with pytest.raises(ValueError, match="distraction_kinds.*background, camera, colour"):
        envs.check("cartpole-swingup", obs_mode="pixels", distraction="easy", distraction_kinds="camera,sky")
    with pytest.raises(ValueError, match="distraction_kinds"):
        envs.check("cartpole-swingup", obs_mode="pixels", distraction="easy", distraction_kinds=())
    with pytest.raises(ValueError, match="pixel obs_mode"):
        envs.check("cartpole-swingup", distraction="easy")
    with pytest.raises(ValueError, match="dynamic"):
        envs.check("cartpole-swingup", obs_mode="pixels", distraction="easy", dynamic="yes")
    with pytest.raises(ValueError, match="background_dir"):
        envs.check("cartpole-swingup", obs_mode="pixels", distraction="easy", background_dir=str(tmp_path / "no"))
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="background_dir"):
        envs.check("cartpole-swingup", obs_mode="pixels", distraction="easy", background_dir=str(tmp_path / "empty"))
    # no background: no directory needed; the kinds are parsed from a command-line string
    config = envs.check("cartpole-swingup", obs_mode="pixels", distraction="hard",
                        distraction_kinds="colour,camera", background_dir=str(tmp_path / "no"))
    assert config.distraction_config().kinds == ("camera", "colour")
    assert envs.check("cartpole-swingup", obs_mode="pixels", distraction="none").distraction is None


def test_undecodable_frame_fails_when_the_env_is_made(tmp_path):
    root = tmp_path / "davis"
    for video in backgrounds.DAVIS17_TRAINING_VIDEOS[:4]:
        (root / video).mkdir(parents=True)
        (root / video / "00000.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(ValueError, match="background_dir"):
        envs.make("cartpole-swingup", obs_mode="pixels", distraction="easy", background_dir=str(root))


@pytest.mark.parametrize("name", ["cheetah-run", "reacher-easy"])
def test_reset_draws_cover_and_stay_inside_their_intervals(name, videos, reset_data):
    env = _layer(name, videos, dynamic=False, difficulty="hard")
    layer = env.distraction
    data = reset_data(env)
    keys = jax.random.split(jax.random.PRNGKey(1), 4000)
    cam_pos, cam_mat, com = layer._camera_now(data)
    from iap_mjx.envs import camera_walk

    starts = jax.jit(jax.vmap(lambda k: camera_walk.start(k, layer.walk_settings, cam_pos, cam_mat, com,
                                                            layer.tracking)))(keys)
    drawn = jax.jit(jax.vmap(lambda k: layer.reset(k, data)))(keys)
    low, high = np.asarray(starts.low[0]), np.asarray(starts.high[0])
    delta = math.pi / 2 * 0.3
    assert np.all(high > low)
    # every sampled quantity: inside, and reaching within 1% of each end (4000 uniform draws
    # miss a 1% end with probability 0.99**4000 ~ 4e-18)
    for values, lo, hi in [(starts.sphere[:, i], low[i], high[i]) for i in range(3)] + [
            (starts.roll, -delta, delta), (drawn.colour.reshape(4000, -1), layer.colour_low.reshape(-1),
                                           layer.colour_high.reshape(-1))]:
        values = np.asarray(values)
        assert np.all(values >= lo - 1e-6) and np.all(values <= hi + 1e-6)
        width = np.maximum(np.asarray(hi) - np.asarray(lo), 1e-12)
        assert np.all(values.min(0) <= lo + 0.01 * width) and np.all(values.max(0) >= hi - 0.01 * width)
    r0 = float(starts.velocity_scale[0]) * 4
    np.testing.assert_allclose([low[0], high[0]], [r0 * (1 - 0.15), r0 * (1 + 0.45)], rtol=1e-5)
    if name == "reacher-easy":  # no upper-quadrant limit: the box is the start +- delta
        np.testing.assert_allclose(high[1:] - low[1:], 2 * delta, rtol=1e-5)
    else:
        assert low[1] >= -math.pi and high[1] <= 0 and low[2] >= 0 and high[2] <= math.pi / 2 + 1e-6
    # after the reset's walk (which clamps the draw into the box) the camera is inside it;
    # static: advancing changes nothing
    sphere = np.asarray(drawn.camera.sphere)
    assert np.all(sphere >= low - 1e-5) and np.all(sphere <= high + 1e-5)
    assert layer.advance(drawn) is drawn
    # background: videos and frames uniform over what exists
    video, frame = np.asarray(drawn.video), np.asarray(drawn.frame)
    assert set(video) == {0, 1, 2}
    for v, length in enumerate(LENGTHS):
        assert set(frame[video == v]) == set(range(length))


def test_dynamic_walks_keep_to_their_boxes_and_caps(videos, reset_data):
    env = _layer("cartpole-swingup", videos, dynamic=True, difficulty="hard", action_repeat=1)
    layer = env.distraction
    data = reset_data(env)
    first = jax.jit(jax.vmap(lambda k: layer.reset(k, data)))(jax.random.split(jax.random.PRNGKey(2), 64))

    def run(p, _):
        q = jax.vmap(layer.advance)(p)
        return q, (q, p)
    _, (after, before) = jax.jit(lambda p: jax.lax.scan(run, p, length=150))(first)
    cam, cam0 = after.camera, before.camera  # leaves (steps, episodes, ...)
    sphere = np.asarray(cam.sphere)
    assert np.all(sphere >= np.asarray(cam.low) - 1e-5) and np.all(sphere <= np.asarray(cam.high) + 1e-5)
    settings = layer.walk_settings
    cap = settings.max_vel * np.asarray(cam.velocity_scale)[..., None][..., 0]
    # the velocity is the move actually made: within the cap unless the box clamped it
    step = np.linalg.norm(np.asarray(cam.velocity), axis=-1)
    moved = np.linalg.norm(np.asarray(camera_xyz(cam)) - np.asarray(camera_xyz(cam0)), axis=-1)
    np.testing.assert_allclose(step, moved, atol=1e-5)
    clamped = np.any((np.abs(sphere - np.asarray(cam.low)) < 1e-6) | (np.abs(sphere - np.asarray(cam.high)) < 1e-6),
                     axis=-1)
    assert np.all(step[~clamped] <= cap[~clamped] + 1e-5) and step.max() > 0.5 * cap.max()
    assert clamped.mean() < 0.5
    roll_step = np.abs(np.asarray(cam.roll) - np.asarray(cam0.roll))
    assert np.all(roll_step <= settings.max_roll_vel + 1e-6) and roll_step.max() > 0
    assert np.all(np.abs(np.asarray(cam.roll)) <= settings.delta + 1e-6)
    colour = np.asarray(after.colour)
    assert np.all(colour >= layer.colour_low - 1e-6) and np.all(colour <= layer.colour_high + 1e-6)
    assert not np.allclose(colour[-1], colour[0]), "the dynamic colours should move"


def camera_xyz(walk):
    from iap_mjx.envs import camera_walk

    return jax.vmap(jax.vmap(camera_walk.to_cartesian))(walk.sphere)


def _reference_ping_pong(frame, direction, length, steps):
    """distracting_control/background.py ``step``'s index update, transcribed."""
    out = []
    for _ in range(steps):
        frame += direction
        if frame <= 0:
            frame = 0
            direction = abs(direction)
        if frame >= length:
            frame = length - 1
            direction = -abs(direction)
        out.append(frame)
    return out


def test_dynamic_background_ping_pongs_as_the_reference(videos, reset_data):
    env = _layer("cartpole-swingup", videos, dynamic=True, action_repeat=3)
    layer = env.distraction
    drawn = jax.jit(jax.vmap(lambda k: layer.reset(k, reset_data(env))))(jax.random.split(jax.random.PRNGKey(3), 32))
    trajectory = [drawn]
    advance = jax.jit(jax.vmap(layer.advance))
    for _ in range(5):
        trajectory.append(advance(trajectory[-1]))
    assert set(np.asarray(drawn.direction)) == {-1, 1}
    for e in range(32):
        length = LENGTHS[int(drawn.video[e])]
        expected = _reference_ping_pong(int(drawn.frame[e]), int(drawn.direction[e]), length, 15)
        got = [int(p.frame[e]) for p in trajectory[1:]]
        assert got == expected[2::3], (e, length, got, expected)  # 3 control steps per env step


def test_same_key_same_perturbation_batches_differ_and_physics_is_untouched(videos):
    env = _layer("cartpole-swingup", videos, dynamic=True)
    base = env.env  # the undistracted task (state observations)
    keys = jax.random.split(jax.random.PRNGKey(4), 6)
    actions = jnp.ones((6, env.action_size))

    @jax.jit
    def run(keys):
        first = jax.vmap(env.reset)(keys)
        moved = jax.vmap(env.step)(first, actions)
        undistracted = jax.vmap(base.step)(jax.vmap(base.reset)(keys), actions)
        frames = jax.vmap(env.render)(moved.data, moved.info["distraction"])
        two = jax.vmap(lambda p: env.distraction.advance(p, 2))(first.info["distraction"])
        return first, moved, undistracted, frames, two

    first, moved, undistracted, frames, two = run(keys)
    again = jax.jit(jax.vmap(env.reset))(keys)
    for a, b in zip(jax.tree.leaves(first.info["distraction"]), jax.tree.leaves(again.info["distraction"])):
        np.testing.assert_array_equal(a, b)
    sphere = np.asarray(first.info["distraction"].camera.sphere)
    colour = np.asarray(first.info["distraction"].colour).reshape(6, -1)
    for i in range(6):
        for j in range(i):
            assert not np.allclose(sphere[i], sphere[j]) and not np.allclose(colour[i], colour[j])
    np.testing.assert_array_equal(moved.data.qpos, undistracted.data.qpos)  # same physics draws
    np.testing.assert_array_equal(moved.reward, undistracted.reward)
    # the frame is the scene of the state's own perturbation; the walk moved 2 control steps
    np.testing.assert_allclose(moved.obs, frames, atol=1e-6)
    np.testing.assert_allclose(moved.info["distraction"].camera.sphere, two.camera.sphere, atol=1e-6)
    np.testing.assert_array_equal(moved.info["distraction"].frame, two.frame)
    assert not np.allclose(moved.info["distraction"].camera.sphere, first.info["distraction"].camera.sphere)
    with pytest.raises(ValueError, match="perturbation"):
        env.render(jax.tree.map(lambda x: x[0], moved.data))
