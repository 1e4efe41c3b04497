"""The distraction layer against the reference code, google-research ``distracting_control/``.

The reference runs here as its PyPI fork ``distracting-control==0.1.1rc3`` (a test-only
dependency). On the paths used here (the wrappers' defaults: no ``fix_*``, uniform sampling)
its ``camera.py``, ``color.py`` and ``suite_utils.py`` compute what the google-research
files at commit 0c1bbe5 compute, statement for statement (checked by reading both). Its
``background.py`` imports OpenCV (not a dependency here) and uploads every frame through an
OpenGL context, so it is not run: its module constants are read from its source with
``ast`` (nothing executed), and the statements of its frame-index walk
(``DistractingBackgroundEnv.step``) are compiled from its source and run on a stand-in wrapper
(:func:`_reference_ping_pong`).

Each test builds our layer (``Distraction``) from our own env and compares what it does with
what the reference's wrappers do on dm_control's env in the same state: the settings a level
implies, the camera's box, velocity scale and look-at point at reset, the walk and the pose
it writes into ``cam_xpos``/``cam_xmat`` over several control steps, the colour box, the
colours the camera then draws (against the geoms and colours MuJoCo's own visualiser,
``mjv_updateScene``, draws with the reference's perturbed materials), the floor's alpha, the
dynamic colour step's size, the background's frame walk, and the distributions of the
reset's camera and colour draws against as many of the reference's own draws.
"""

from __future__ import annotations

import ast
import copy
import functools
import math
import types
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx
from scipy import stats

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    import distracting_control
    from distracting_control import camera as ref_camera
    from distracting_control import color as ref_color
    from distracting_control import suite_utils as ref_suite
from dm_control import suite

from iap_mjx import envs
from iap_mjx.configs import background_sets
from iap_mjx.configs import distraction as dcs
from iap_mjx.envs import backgrounds, camera_walk, distraction
from iap_mjx.envs.pixels import with_pixels
from iap_mjx.envs.registry import _task_classes

ATOL = 2e-5  # float32 against the reference's float64: matrix entries and metres (|x| < 10)
REFERENCE_BACKGROUND = Path(distracting_control.__file__).parent / "background.py"


def _f32(x):
    return jnp.asarray(np.asarray(x, np.float64), jnp.float32)


def _videos(lengths=(5, 3, 1), size=8):
    frames = np.random.default_rng(0).integers(0, 256, (len(lengths), max(lengths), size, size, 3), np.uint8)
    return backgrounds.BackgroundVideos(
        frames=frames, lengths=np.asarray(lengths, np.int32), names=tuple("abc"[: len(lengths)]), source="test"
    )


@functools.cache
def _base(task, action_repeat=1):
    return _task_classes()[task](envs.EnvConfig(action_repeat=action_repeat))


def _layer(task, difficulty="hard", dynamic=True, kinds=dcs.KINDS, action_repeat=1, videos=None):
    base = _base(task, action_repeat)
    config = dcs.DistractionConfig(difficulty=difficulty, dynamic=dynamic, kinds=kinds)
    if "background" in kinds and videos is None:
        videos = _videos()
    return with_pixels(base, height=8, width=8, distraction=config, videos=videos)


def _reference_constant(name):
    """A module-level constant of the reference's ``background.py``, read without running it."""
    tree = ast.parse(REFERENCE_BACKGROUND.read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == name for t in node.targets):
            return ast.literal_eval(node.value)
    raise KeyError(name)


def test_levels_and_settings_are_the_reference_modules():
    assert dcs.DIFFICULTY_SCALE == ref_suite.DIFFICULTY_SCALE
    for level in dcs.DIFFICULTY_SCALE:
        assert dcs.num_videos(level) == ref_suite.DIFFICULTY_NUM_VIDEOS[level]
    assert list(background_sets.DAVIS17_TRAINING_VIDEOS) == _reference_constant("DAVIS17_TRAINING_VIDEOS")
    # the reference's six domains (its get_camera_kwargs asserts them), one task each
    assert sorted(t.split("-")[0] for t in dcs.TASKS) == sorted(
        ["reacher", "cartpole", "finger", "cheetah", "ball_in_cup", "walker"]
    )
    videos = _videos()
    for task in dcs.TASKS:
        domain = task.split("-")[0]
        env = _layer(task, "medium", False)
        for level, scale in ref_suite.DIFFICULTY_SCALE.items():
            for dynamic in (False, True):
                layer = distraction.Distraction(env.env, env.camera, dcs.DistractionConfig(level, dynamic), videos)
                kwargs = ref_suite.get_camera_kwargs(domain, scale, dynamic)
                s = layer.walk_settings
                ours = dict(
                    vertical_delta=s.delta,
                    horizontal_delta=s.delta,
                    roll_delta=s.delta,
                    vel_std=s.vel_std,
                    max_vel=s.max_vel,
                    roll_std=s.roll_std,
                    max_roll_vel=s.max_roll_vel,
                    max_zoom_in_percent=s.zoom_in,
                    max_zoom_out_percent=s.zoom_out,
                    limit_to_upper_quadrant=s.upper_quadrant,
                )
                assert ours.keys() == kwargs.keys()
                for key, value in kwargs.items():
                    assert ours[key] == pytest.approx(value, abs=1e-12), (task, level, dynamic, key)
                colour = ref_suite.get_color_kwargs(scale, dynamic)
                assert layer.colour_step == pytest.approx(colour["step_std"], abs=1e-12)
                assert layer.colour_delta == pytest.approx(colour["max_delta"], abs=1e-12)
        # the floor's alpha: the background wrapper's ground_plane_alpha, in the model the
        # camera draws (alpha 0: not drawn at all, as MuJoCo skips it)
        alpha = ref_suite.get_background_kwargs(domain, None, False, None)["ground_plane_alpha"]
        grid = mujoco.mj_name2id(env.mj_model, mujoco.mjtObj.mjOBJ_MATERIAL, "grid")
        floors = [g for g in range(env.mj_model.ngeom) if env.mj_model.geom_matid[g] == grid]
        drawn = [k for k, g in enumerate(env.camera.scene.geom_ids) if g in floors]
        assert floors, task
        if alpha == 0.0:
            assert not drawn, task
        else:
            assert len(drawn) == len(floors), task
            np.testing.assert_allclose(env.camera.scene.geom_alpha[drawn], alpha, atol=1e-7, err_msg=task)


def test_rotations_and_coordinates_match_the_reference_functions():
    rng = np.random.default_rng(0)
    n = 200
    target, position = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)) * 3
    roll = rng.uniform(-np.pi, np.pi, n)
    sphere = np.stack([rng.uniform(0.5, 4, n), rng.uniform(-np.pi, np.pi, n), rng.uniform(-0.5, np.pi, n)], -1)
    euler = rng.uniform(-np.pi, np.pi, (n, 3))

    @jax.jit
    @jax.vmap
    def ours(t, p, r, s, e):
        return (
            camera_walk.look_at_upright(t, p),
            camera_walk.look_at_rotation(t, p),
            camera_walk.rz(r),
            camera_walk.to_sphere(p),
            camera_walk.to_cartesian(s),
            camera_walk.rz(e[2]) @ camera_walk._rx(e[0]),
        )  # eul2mat([x, 0, z]), composed

    got = [np.asarray(x) for x in ours(*map(_f32, (target, position, roll, sphere, euler)))]
    for i in range(n):
        expected = (
            ref_camera.get_lookat_xmat_no_roll(target[i].copy(), position[i].copy()).reshape(3, 3),
            ref_camera.get_lookat_xmat(target[i].copy(), position[i].copy()),
            ref_camera.rotvec2mat(roll[i], np.array([0.0, 0.0, 1.0])),
            ref_camera.cart2sphere(position[i]),
            ref_camera.sphere2cart(sphere[i]),
            ref_camera.eul2mat([euler[i, 0], 0.0, euler[i, 2]]),
        )
        for k, e in enumerate(expected):
            np.testing.assert_allclose(got[k][i], e, atol=ATOL, err_msg=f"case {i} function {k}")


def _snapshot(ref):
    """The reference camera wrapper's walk state and box, as our ``CameraWalk``."""
    return camera_walk.CameraWalk(
        sphere=_f32([ref._radius, ref._h_angle, ref._v_angle]),
        roll=_f32(ref._roll),
        velocity=_f32(ref._camera_vel),
        roll_velocity=_f32(ref._roll_vel),
        low=_f32([ref._min_radius, ref._min_h_angle, ref._min_v_angle]),
        high=_f32([ref._max_radius, ref._max_h_angle, ref._max_v_angle]),
        velocity_scale=_f32(ref._vel_scaling),
        lookat=_f32(ref._cam_initial_lookat_point),
    )


@pytest.mark.parametrize("task", dcs.TASKS)
def test_layer_matches_the_reference_wrappers_on_dm_control(task):
    """Fixed cameras (cartpole, ball_in_cup, finger), tracking cameras (cheetah, walker) and
    the axis-angle look-at without the upper-quadrant limit (reacher); hard, dynamic."""
    domain, name = task.split("-")
    env = suite.load(domain, name, task_kwargs={"random": 3})
    physics = env.physics
    ref_cam = ref_camera.DistractingCameraEnv(
        env, camera_id=0, seed=7, **ref_suite.get_camera_kwargs(domain, 0.3, True)
    )
    ref_col = ref_color.DistractingColorEnv(env, seed=8, **ref_suite.get_color_kwargs(0.3, True))
    pixel_env = _layer(task, "hard", True, kinds=("camera", "colour"))
    layer = pixel_env.distraction

    @jax.jit
    def ours(key, data, before, noise, roll_noise, colour):
        drawn = layer.reset(key, data).camera
        walked = camera_walk.walk(before, layer.walk_settings, noise, roll_noise)
        scene_data, inputs = layer.scene(data, distraction.Perturbation(key=key, camera=walked, colour=colour))
        return drawn, walked, scene_data.cam_xpos[0], scene_data.cam_xmat[0], inputs["geom_rgb"]

    env.reset()
    ref_cam.setup_camera()
    ref_col._reset_color()
    rng = np.random.default_rng(1)
    spec = env.action_spec()
    key = jax.random.PRNGKey(0)
    for step in range(5):
        if step:
            env.step(rng.uniform(spec.minimum, spec.maximum))  # the physics moves the camera
        data = mjx.put_data(physics.model.ptr, physics.data.ptr)  # the unperturbed camera
        before = _snapshot(ref_cam)
        draws = copy.deepcopy(ref_cam._random_state)  # the noise _apply is about to draw
        noise, roll_noise = draws.randn(3), draws.randn()
        ref_cam._apply()
        drawn, walked, cam_xpos, cam_xmat, geom_rgb = ours(
            key, data, before, _f32(noise), _f32(roll_noise), _f32(ref_col._current_rgb)
        )
        if step == 0:  # the reset's box, velocity scale and look-at point, from the same state
            for field in ("low", "high", "velocity_scale", "lookat"):
                np.testing.assert_allclose(
                    getattr(drawn, field), getattr(before, field), atol=ATOL, err_msg=f"{task} {field}"
                )
        after = _snapshot(ref_cam)
        for field in ("sphere", "roll", "velocity", "roll_velocity"):
            np.testing.assert_allclose(
                getattr(walked, field), getattr(after, field), atol=ATOL, err_msg=f"{task} step {step} {field}"
            )
        np.testing.assert_allclose(cam_xpos, physics.data.cam_xpos[0], atol=ATOL, err_msg=f"{task} cam_xpos")
        np.testing.assert_allclose(
            cam_xmat, physics.data.cam_xmat[0].reshape(3, 3), atol=ATOL, err_msg=f"{task} cam_xmat"
        )
    assert np.linalg.norm(np.asarray(after.velocity)) > 0, "the dynamic camera should move"
    # colours: the reference's box around dm_control's materials; and what MuJoCo's own
    # visualiser draws with the reference's perturbed materials (the wrapper writes them into
    # dm_control's model): mjv_updateScene's geoms, the ones the renderer rasterises, each in
    # the rgba MuJoCo gives it, against our camera's geoms and the colours our layer hands it
    np.testing.assert_allclose(layer.colour_low, ref_col._min_rgb, atol=1e-6)
    np.testing.assert_allclose(layer.colour_high, ref_col._max_rgb, atol=1e-6)
    np.testing.assert_allclose(physics.model.mat_rgba[:, :3], ref_col._current_rgb, atol=1e-7)  # float32
    drawn, others = _mujoco_drawn(physics.model.ptr, physics.data.ptr)
    assert sorted(drawn) == sorted(pixel_env.camera.scene.geom_ids.tolist()), task
    expected = np.stack([drawn[g][:3] for g in pixel_env.camera.scene.geom_ids.tolist()])
    np.testing.assert_allclose(geom_rgb, expected, atol=1e-6, err_msg=task)
    assert not np.allclose(geom_rgb, pixel_env.camera.scene.geom_rgb, atol=1e-3)
    # what else MuJoCo draws (ball_in_cup's string and sites, which our camera does not) keeps
    # its colour under the perturbation: the colour distraction changes geoms only
    original = copy.copy(physics.model.ptr)
    original.mat_rgba[:, :3] = ref_col._original_rgb
    unperturbed = _mujoco_drawn(original, physics.data.ptr)[1]
    assert [o[:2] for o in others] == [o[:2] for o in unperturbed], task
    for (kind, index, rgba), (_, _, before) in zip(others, unperturbed):
        np.testing.assert_array_equal(rgba, before, err_msg=f"{task}: object type {kind} {index}")


def _mujoco_drawn(model, data):
    """What MuJoCo's renderer draws from camera 0 (``mjv_updateScene`` with the default
    ``mjvOption``: geom groups 0-2): ``({geom id: (4,) rgba}, [(object type, id, (4,) rgba)]
    of everything else)``, each in the rgba of its ``mjvGeom`` (for a geom: its material's or
    its own, as MuJoCo chooses)."""
    scene = mujoco.MjvScene(model, maxgeom=10_000)
    camera = mujoco.MjvCamera()
    camera.type, camera.fixedcamid = mujoco.mjtCamera.mjCAMERA_FIXED, 0
    mujoco.mjv_updateScene(
        model, data, mujoco.MjvOption(), mujoco.MjvPerturb(), camera, mujoco.mjtCatBit.mjCAT_ALL, scene
    )
    geoms = [scene.geoms[i] for i in range(scene.ngeom)]
    drawn = {int(g.objid): np.array(g.rgba) for g in geoms if g.objtype == mujoco.mjtObj.mjOBJ_GEOM}
    others = [(int(g.objtype), int(g.objid), np.array(g.rgba)) for g in geoms if g.objtype != mujoco.mjtObj.mjOBJ_GEOM]
    return drawn, others


def test_dynamic_colour_step_has_the_reference_size():
    """One control step of the dynamic colours: Gaussian with the reference's ``step_std``
    per channel (``get_color_kwargs``), within the box. 3000 episodes x M materials x 3
    channels away from the box's edges: the sample std's relative standard error is
    ``1 / sqrt(2 n)`` < 0.5%; the bound is 5 of them (a step 10% off fails)."""
    layer = _layer("cheetah-run", "medium", True, kinds=("colour",)).distraction
    data = None  # the colour draw reads no state
    keys = jax.random.split(jax.random.PRNGKey(5), 3000)
    before, after = jax.jit(jax.vmap(lambda k: (lambda p: (p, layer.advance(p, 1)))(layer.reset(k, data))))(keys)
    before, after = np.asarray(before.colour, np.float64), np.asarray(after.colour, np.float64)
    assert np.all(after >= layer.colour_low - 1e-6) and np.all(after <= layer.colour_high + 1e-6)
    expected = ref_suite.get_color_kwargs(0.2, True)["step_std"]
    inside = (
        (before - layer.colour_low > 6 * expected)
        & (layer.colour_high - before > 6 * expected)
        & (np.broadcast_to(layer.colour_high - layer.colour_low, before.shape) > 0)
    )
    steps = (after - before)[inside]
    n = steps.size
    assert n > 20000, n
    assert abs(steps.mean()) < 5 * expected / math.sqrt(n)
    assert abs(steps.std() / expected - 1) < 5 / math.sqrt(2 * n), steps.std() / expected


@functools.cache
def _reference_frame_walk() -> types.CodeType:
    """The frame-index walk of the reference's ``DistractingBackgroundEnv.step`` (the body of
    its ``if self._dynamic and self._video_paths:``, without the texture upload
    ``self._apply()``), compiled from its source with ``ast``: the reference's own statements."""
    tree = ast.parse(REFERENCE_BACKGROUND.read_text())
    (wrapper,) = [n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "DistractingBackgroundEnv"]
    (step,) = [n for n in wrapper.body if isinstance(n, ast.FunctionDef) and n.name == "step"]
    (walk,) = [n for n in step.body if isinstance(n, ast.If) and "self._dynamic" in ast.unparse(n.test)]
    body = [n for n in walk.body if ast.unparse(n) != "self._apply()"]
    assert len(body) == len(walk.body) - 1, ast.unparse(walk)
    return compile(ast.Module(body=body, type_ignores=[]), str(REFERENCE_BACKGROUND), "exec")


def _reference_ping_pong(frame, direction, length, steps):
    """The reference's frame index after each of ``steps`` dynamic steps of a video of
    ``length`` frames, its statements (:func:`_reference_frame_walk`) run on a stand-in
    wrapper holding only what they read and write."""
    wrapper = types.SimpleNamespace(
        _current_img_index=frame, _step_direction=direction, _background=types.SimpleNamespace(textures=[None] * length)
    )
    out = []
    for _ in range(steps):
        exec(_reference_frame_walk(), {"self": wrapper})
        out.append(wrapper._current_img_index)
    return out


def test_dynamic_background_walks_frames_as_the_reference():
    lengths = (5, 3, 1)
    env = _layer("cartpole-swingup", "medium", True, kinds=("background",), action_repeat=3, videos=_videos(lengths))
    layer = env.distraction

    @jax.jit
    def run(keys):
        first = jax.vmap(lambda k: layer.reset(k, None))(keys)
        return first, jax.lax.scan(lambda p, _: (jax.vmap(layer.advance)(p),) * 2, first, length=5)[1]

    first, trajectory = run(jax.random.split(jax.random.PRNGKey(3), 32))
    assert set(np.asarray(first.direction)) == {-1, 1}
    for e in range(32):
        length = lengths[int(first.video[e])]
        expected = _reference_ping_pong(int(first.frame[e]), int(first.direction[e]), length, 15)
        got = list(np.asarray(trajectory.frame[:, e]))
        assert got == expected[2::3], (e, length, got, expected)  # 3 control steps per env step


@pytest.mark.parametrize("task", ["cheetah-run", "reacher-easy"])
def test_reset_draws_are_distributed_as_the_reference_draws(task):
    """The camera's reset draw (``camera_walk.start``: radius, angles, roll, the velocity's
    direction and size, the roll velocity) and the colours' (``Distraction.reset``) against as
    many of the reference's own draws (``DistractingCameraEnv.setup_camera``,
    ``DistractingColorEnv._reset_color``) from the same state: the two-sample mean,
    covariance and KS tests of ``test_envs_parity`` at its family-wise false-alarm rate.
    Hard and dynamic (the velocities are drawn only then); a tracking camera with the
    upper-quadrant limit (cheetah) and a fixed one without it (reacher)."""
    from test_envs_parity import _assert_same_distribution

    n = 4096
    domain, name = task.split("-")
    env = suite.load(domain, name, task_kwargs={"random": 3})
    env.reset()
    ref_cam = ref_camera.DistractingCameraEnv(
        env, camera_id=0, seed=7, **ref_suite.get_camera_kwargs(domain, dcs.DIFFICULTY_SCALE["hard"], True)
    )
    ref_col = ref_color.DistractingColorEnv(
        env, seed=8, **ref_suite.get_color_kwargs(dcs.DIFFICULTY_SCALE["hard"], True)
    )
    theirs_camera, theirs_colour = [], []
    for _ in range(n):
        ref_cam.setup_camera()
        ref_col._reset_color()
        theirs_camera.append(
            np.concatenate(
                [
                    [ref_cam._radius, ref_cam._h_angle, ref_cam._v_angle, ref_cam._roll],
                    ref_cam._camera_vel,
                    [ref_cam._roll_vel],
                ]
            )
        )
        theirs_colour.append(np.ravel(ref_col._current_rgb))

    layer = _layer(task, "hard", True, kinds=("camera", "colour")).distraction
    data = mjx.put_data(env.physics.model.ptr, env.physics.data.ptr)

    @jax.jit
    def ours(keys):
        cam_pos, cam_mat, com = layer._camera_now(data)
        drawn = jax.vmap(lambda k: camera_walk.start(k, layer.walk_settings, cam_pos, cam_mat, com, layer.tracking))(
            keys
        )
        colour = jax.vmap(lambda k: layer.reset(k, data).colour)(keys)
        camera = jnp.concatenate(
            [drawn.sphere, drawn.roll[:, None], drawn.velocity, drawn.roll_velocity[:, None]], axis=1
        )
        return camera, colour.reshape(len(keys), -1)

    camera, colour = ours(jax.random.split(jax.random.PRNGKey(5), n))
    _assert_same_distribution(np.asarray(camera, np.float64), np.array(theirs_camera))
    _assert_same_distribution(np.asarray(colour, np.float64), np.array(theirs_colour))

    # The velocity's direction against the closed form, which the moments above see only
    # weakly: each coordinate of a uniform unit vector in 3-D is uniform on [-1, 1]
    # (Archimedes). A direction drawn in a cube and normalised (the corners too dense) fails.
    def uniform_coordinates(directions: np.ndarray) -> bool:
        level = 1e-3 / 3  # family-wise false-alarm rate 1e-3 over the three coordinates
        return all(stats.kstest(directions[:, i], "uniform", args=(-1.0, 2.0)).pvalue > level for i in range(3))

    velocity = np.asarray(camera[:, 4:7], np.float64)
    assert uniform_coordinates(velocity / np.linalg.norm(velocity, axis=1, keepdims=True))
    cube = np.random.default_rng(0).uniform(-1.0, 1.0, (n, 3))
    assert not uniform_coordinates(cube / np.linalg.norm(cube, axis=1, keepdims=True))
