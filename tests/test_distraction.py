"""The distraction layer's own behaviour: settings fail early and clearly, samples cover and
stay inside their intervals, dynamic walks keep to their boxes and step caps, each kind
switches on alone. Agreement with the reference code is ``test_distraction_reference.py``;
the layer inside the pixel env (determinism, k walks per env step, physics untouched) is
``test_dcs_presets.py``'s episode.

Walks and draws run on a small synthetic set of background videos (the loader itself is
tested in ``test_backgrounds.py``); every test compiles one program."""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest
from mujoco import mjx

from iap_mjx import envs
from iap_mjx.configs import background_sets
from iap_mjx.configs import distraction as dcs
from iap_mjx.envs import backgrounds, camera_walk
from iap_mjx.envs.pixels import with_pixels
from iap_mjx.envs.registry import _task_classes
from iap_mjx.viz import render_compare

SIZE = (24, 32)
LENGTHS = (5, 3, 1)


@pytest.fixture(scope="module")
def videos():
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (len(LENGTHS), max(LENGTHS), 16, 16, 3), dtype=np.uint8)
    return backgrounds.BackgroundVideos(
        frames=frames, lengths=np.asarray(LENGTHS, np.int32), names=("a", "b", "c"), source="test"
    )


def _layer(name, videos, dynamic, difficulty="medium", action_repeat=2, kinds=dcs.KINDS):
    base = _task_classes()[name](envs.EnvConfig(action_repeat=action_repeat))
    config = dcs.DistractionConfig(difficulty=difficulty, dynamic=dynamic, kinds=kinds)
    return with_pixels(
        base, height=SIZE[0], width=SIZE[1], distraction=config, videos=videos if "background" in kinds else None
    )


def _dm_state(name):
    """A dm_control state of ``name`` as ``mjx.Data`` (the camera draw reads its camera)."""
    ((model, data),) = render_compare.suite_states(*name.split("-"), n_states=1, seed=0)
    return mjx.put_data(model, data)


def test_bad_settings_fail_before_compiling_naming_the_setting(tmp_path):
    check = envs.check
    px = dict(obs_mode="pixels")
    cases = [
        (dict(distraction="medum"), r"distraction = 'medum'.*easy, medium, hard"),
        (dict(distraction=["medium"]), r"distraction = \['medium'\].*easy, medium, hard"),
        (dict(distraction="easy", distraction_kinds="camera,sky"), "distraction_kinds.*background, camera, colour"),
        (dict(distraction="easy", distraction_kinds=()), "distraction_kinds"),
        (dict(distraction="easy", dynamic="yes"), "dynamic"),
        (dict(distraction="easy", background_dir=str(tmp_path / "no")), "background_dir"),
        (dict(distraction="easy", background_size=0), "background_size must be an int >= 1"),
        (dict(distraction="easy", background_size=4096), "background_size = 4096.*valid 1 to 1024"),
        (dict(distraction="hard", background_size=1024, background_frames=200), "background_size = 1024.*GiB"),
        (dict(distraction="easy", background_frames=0), "background_frames"),
        (dict(distraction="easy", camera_id=1), "camera_id = 1.*valid camera_id: 0"),
        (
            dict(distraction="easy", distraction_kinds="camera", background_dir=str(tmp_path)),
            "background_dir.*background distraction is off",
        ),
        # distraction-only settings without a distraction are refused, not ignored
        (dict(dynamic=True), "dynamic=True set without a distraction.*easy, medium, hard"),
        (dict(background_dir=str(tmp_path)), "background_dir=.*without a distraction"),
        (dict(distraction_kinds="camera"), "distraction_kinds=.*without a distraction"),
        (dict(background_size=64), "background_size=64 set without a distraction"),
    ]
    for overrides, message in cases:
        with pytest.raises(ValueError, match=message):
            check("cartpole-swingup", **px, **overrides)
    with pytest.raises(ValueError, match="pixel obs_mode"):
        check("cartpole-swingup", distraction="easy")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="background_dir"):
        check("cartpole-swingup", **px, distraction="easy", background_dir=str(tmp_path / "empty"))
    message = (
        "'quadruped-flat' is not a Distracting Control Suite task; valid: cheetah-run, walker-walk, "
        "cartpole-swingup, ball_in_cup-catch, reacher-easy, finger-spin"
    )
    with pytest.raises(ValueError, match=message):
        check("quadruped-flat", **px, distraction="medium")
    # no background: no directory needed; the kinds are parsed from a command-line string
    config = check("cartpole-swingup", **px, distraction="hard", distraction_kinds="colour,camera")
    assert config.distraction_config().kinds == ("camera", "colour")
    assert check("cartpole-swingup", **px, distraction="none").distraction is None
    root = tmp_path / "davis"  # listed, not decoded, before anything compiles
    for video in background_sets.DAVIS17_TRAINING_VIDEOS[:4]:
        (root / video).mkdir(parents=True)
        (root / video / "00000.jpg").write_bytes(b"not decoded by check")
    config = check("cartpole-swingup", **px, distraction="easy", background_dir=root)
    assert config.background_dir == str(root) and hash(config)  # a Path is kept as a (hashable) str


def test_undecodable_frame_fails_when_the_env_is_made(tmp_path):
    root = tmp_path / "davis"
    for video in background_sets.DAVIS17_TRAINING_VIDEOS[:4]:
        (root / video).mkdir(parents=True)
        (root / video / "00000.jpg").write_bytes(b"not a jpeg")
    with pytest.raises(ValueError, match="background_dir"):
        envs.make("cartpole-swingup", obs_mode="pixels", distraction="easy", background_dir=str(root))


def test_reset_draws_cover_and_stay_inside_their_intervals(videos):
    """cheetah (tracking camera, upper quadrant) and reacher (fixed, no limit), hard: every
    drawn quantity inside its interval and reaching within 1% of each end (4000 uniform
    draws miss a 1% end with probability 0.99**4000 ~ 4e-18); videos and frames uniform over
    what exists. The camera's draw is ``camera_walk.start``'s; the reset's first walk then
    maps it through Cartesian coordinates into the box (as the reference's first ``_apply``:
    a negative polar angle becomes a positive one), so after it the camera is inside the box.
    Static: advancing changes nothing."""
    layers = {
        name: _layer(name, videos, dynamic=False, difficulty="hard").distraction
        for name in ("cheetah-run", "reacher-easy")
    }
    states = {name: _dm_state(name) for name in layers}
    keys = jax.random.split(jax.random.PRNGKey(1), 4000)

    def draws(layer, state):
        cam_pos, cam_mat, com = layer._camera_now(state)
        start = jax.vmap(lambda k: camera_walk.start(k, layer.walk_settings, cam_pos, cam_mat, com, layer.tracking))(
            keys
        )
        return start, jax.vmap(lambda k: layer.reset(k, state))(keys)

    drawn = jax.jit(lambda states: {name: draws(layer, states[name]) for name, layer in layers.items()})(states)
    delta = math.pi / 2 * 0.3
    for name, layer in layers.items():
        start, p = drawn[name]
        low, high = np.asarray(p.camera.low[0]), np.asarray(p.camera.high[0])
        assert np.all(high > low)
        r0 = float(p.camera.velocity_scale[0]) * 4
        np.testing.assert_allclose([low[0], high[0]], [r0 * (1 - 0.15), r0 * (1 + 0.45)], rtol=1e-5)
        if name == "reacher-easy":  # no upper-quadrant limit: the box is the start +- delta
            np.testing.assert_allclose(high[1:] - low[1:], 2 * delta, rtol=1e-5)
        else:
            assert low[1] >= -math.pi and high[1] <= 0 and low[2] >= 0 and high[2] <= math.pi / 2 + 1e-6
            assert high[1] - low[1] < 2 * delta - 1e-3 or high[2] - low[2] < 2 * delta - 1e-3, "limit unused"
        sphere = np.asarray(p.camera.sphere)
        assert np.all(sphere >= low - 1e-5) and np.all(sphere <= high + 1e-5), name
        for values, lo, hi in [(start.sphere[:, i], low[i], high[i]) for i in range(3)] + [
            (p.camera.roll, -delta, delta),
            (p.colour.reshape(len(keys), -1), layer.colour_low.reshape(-1), layer.colour_high.reshape(-1)),
        ]:
            values = np.asarray(values)
            assert np.all(values >= lo - 1e-6) and np.all(values <= hi + 1e-6), name
            width = np.maximum(np.asarray(hi) - np.asarray(lo), 1e-12)
            assert np.all(values.min(0) <= lo + 0.01 * width) and np.all(values.max(0) >= hi - 0.01 * width)
        assert np.all(np.asarray(p.direction) == 0)
        assert layer.advance(p) is p
        video, frame = np.asarray(p.video), np.asarray(p.frame)
        assert set(video) == {0, 1, 2}
        for v, length in enumerate(LENGTHS):
            assert set(frame[video == v]) == set(range(length))


def test_dynamic_walks_keep_to_their_boxes_and_caps(videos):
    """Hard, dynamic, 64 episodes x 150 control steps: the camera stays in its box, the
    velocity is the move actually made and within ``max_vel * r0/4`` unless the box clamped
    it, the roll steps within ``max_roll_vel``, colours inside their box and moving."""
    layer = _layer("cartpole-swingup", videos, dynamic=True, difficulty="hard", action_repeat=1).distraction
    data = _dm_state("cartpole-swingup")

    @jax.jit
    def run(keys):
        first = jax.vmap(lambda k: layer.reset(k, data))(keys)
        _, (after, before) = jax.lax.scan(lambda p, _: (q := jax.vmap(layer.advance)(p), (q, p)), first, length=150)
        to_xyz = jax.vmap(jax.vmap(camera_walk.to_cartesian))
        return after, before, to_xyz(after.camera.sphere), to_xyz(before.camera.sphere)

    after, before, xyz, xyz0 = run(jax.random.split(jax.random.PRNGKey(2), 64))
    cam, cam0 = after.camera, before.camera  # leaves (steps, episodes, ...)
    sphere, low, high = np.asarray(cam.sphere), np.asarray(cam.low), np.asarray(cam.high)
    assert np.all(sphere >= low - 1e-5) and np.all(sphere <= high + 1e-5)
    settings = layer.walk_settings
    cap = settings.max_vel * np.asarray(cam.velocity_scale)
    step = np.linalg.norm(np.asarray(cam.velocity), axis=-1)
    np.testing.assert_allclose(step, np.linalg.norm(np.asarray(xyz) - np.asarray(xyz0), axis=-1), atol=1e-5)
    clamped = np.any((np.abs(sphere - low) < 1e-6) | (np.abs(sphere - high) < 1e-6), axis=-1)
    assert np.all(step[~clamped] <= cap[~clamped] + 1e-5) and step.max() > 0.5 * cap.max()
    assert clamped.mean() < 0.5
    roll_step = np.abs(np.asarray(cam.roll) - np.asarray(cam0.roll))
    assert np.all(roll_step <= settings.max_roll_vel + 1e-6) and roll_step.max() > 0.5 * settings.max_roll_vel
    assert np.all(np.abs(np.asarray(cam.roll)) <= settings.delta + 1e-6)
    colour = np.asarray(after.colour)
    assert np.all(colour >= layer.colour_low - 1e-6) and np.all(colour <= layer.colour_high + 1e-6)
    assert not np.allclose(colour[-1], colour[0]), "the dynamic colours should move"


def test_each_kind_switches_on_alone(videos):
    """One kind at a time: only its part of the scene changes (the camera pose, the geoms'
    colours, the sky and the floor's alpha), drawn from the episode's key."""
    name = "cartpole-swingup"
    envs_by_kind = {kind: _layer(name, videos, dynamic=False, kinds=(kind,)) for kind in dcs.KINDS}
    data = _dm_state(name)

    @jax.jit
    def scenes(key):
        return {
            kind: env.distraction.scene(data, env.distraction.reset(key, data)) for kind, env in envs_by_kind.items()
        }

    out = scenes(jax.random.PRNGKey(7))
    plain = with_pixels(_task_classes()[name](), height=SIZE[0], width=SIZE[1])
    for kind, (scene_data, inputs) in out.items():
        moved = not np.allclose(scene_data.cam_xmat[0], data.cam_xmat[0])
        assert moved == (kind == "camera"), kind
        assert set(inputs) == {"camera": set(), "colour": {"geom_rgb"}, "background": {"sky_texture"}}[kind]
        transparent = envs_by_kind[kind].camera.scene.geom_alpha < 1
        assert transparent.any() == (kind == "background"), kind  # cartpole's floor: 0.3
    assert not np.allclose(out["colour"][1]["geom_rgb"], plain.camera.scene.geom_rgb)
    np.testing.assert_array_equal(out["camera"][0].geom_xpos, data.geom_xpos)
