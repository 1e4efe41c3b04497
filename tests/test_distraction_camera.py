"""The camera perturbation against the reference's own code.

The reference is google-research ``distracting_control/camera.py``; its PyPI fork
``distracting-control`` (a test-only dependency; its ``camera.py`` keeps the reference's
functions and ``_apply`` unchanged) runs here on dm_control's own envs. For the same
spherical state, roll, velocity and noise, our ``camera_walk`` must give the reference's
next state and the ``cam_xpos``/``cam_xmat`` it writes into the physics, to float32
tolerance: fixed cameras (cartpole, ball_in_cup, finger), tracking cameras (cheetah,
walker) and the axis-angle look-at without the upper-quadrant limit (reacher).
"""

from __future__ import annotations

import copy
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from distracting_control import camera as reference
    from distracting_control import suite_utils as reference_settings
from dm_control import suite

from iap_mjx.envs import camera_walk

TASKS = (("cheetah", "run"), ("walker", "walk"), ("cartpole", "swingup"),
         ("ball_in_cup", "catch"), ("reacher", "easy"), ("finger", "spin"))
ATOL = 2e-5  # float32 against the reference's float64: matrix entries and metres (|x| < 10)


def _f32(x):
    return jnp.asarray(np.asarray(x, np.float64), jnp.float32)


def test_rotations_and_coordinates_match_the_reference_functions():
    rng = np.random.default_rng(0)
    for _ in range(200):
        target, position = rng.normal(size=3), rng.normal(size=3) * 3
        np.testing.assert_allclose(
            camera_walk.look_at_upright(_f32(target), _f32(position)),
            reference.get_lookat_xmat_no_roll(target.copy(), position.copy()).reshape(3, 3), atol=ATOL)
        np.testing.assert_allclose(
            camera_walk.look_at_rotation(_f32(target), _f32(position)),
            reference.get_lookat_xmat(target.copy(), position.copy()), atol=ATOL)
        roll = rng.uniform(-np.pi, np.pi)
        np.testing.assert_allclose(camera_walk.rz(_f32(roll)),
                                   reference.rotvec2mat(roll, np.array([0.0, 0.0, 1.0])), atol=ATOL)
        np.testing.assert_allclose(camera_walk.to_sphere(_f32(position)), reference.cart2sphere(position),
                                   atol=ATOL)
        sphere = np.array([rng.uniform(0.5, 4), rng.uniform(-np.pi, np.pi), rng.uniform(-0.5, np.pi)])
        np.testing.assert_allclose(camera_walk.to_cartesian(_f32(sphere)), reference.sphere2cart(sphere),
                                   atol=ATOL)
    # the reference's Euler convention, composed the other way round in ours
    angles = rng.uniform(-np.pi, np.pi, 3)
    ours = camera_walk.rz(_f32(angles[2])) @ camera_walk._rx(_f32(angles[0]))
    np.testing.assert_allclose(ours, reference.eul2mat([angles[0], 0.0, angles[2]]), atol=ATOL)


def _snapshot(ref):
    """The reference wrapper's walk state and box, as our ``CameraWalk``."""
    return camera_walk.CameraWalk(
        sphere=_f32([ref._radius, ref._h_angle, ref._v_angle]), roll=_f32(ref._roll),
        velocity=_f32(ref._camera_vel), roll_velocity=_f32(ref._roll_vel),
        low=_f32([ref._min_radius, ref._min_h_angle, ref._min_v_angle]),
        high=_f32([ref._max_radius, ref._max_h_angle, ref._max_v_angle]),
        velocity_scale=_f32(ref._vel_scaling), lookat=_f32(ref._cam_initial_lookat_point))


@pytest.mark.parametrize("domain,task", TASKS)
@pytest.mark.parametrize("dynamic", [False, True])
def test_walk_and_pose_match_the_reference_apply(domain, task, dynamic):
    env = suite.load(domain, task, task_kwargs={"random": 3})
    kwargs = reference_settings.get_camera_kwargs(domain, 0.2, dynamic)
    ref = reference.DistractingCameraEnv(env, camera_id=0, seed=7, **kwargs)
    settings = camera_walk.WalkSettings.make(0.2, dynamic, upper_quadrant=domain != "reacher")
    assert settings.upper_quadrant == kwargs["limit_to_upper_quadrant"]
    tracking = reference.CAMERA_MODES[env.physics.model.cam_mode[0]] == "trackcom"
    assert tracking == (domain in ("cheetah", "walker"))
    physics = env.physics
    rng = np.random.default_rng(1)
    spec = env.action_spec()
    env.reset()
    ref.setup_camera()
    data = physics.named.data
    cam_pos, cam_mat = np.array(data.cam_xpos[0]), np.array(data.cam_xmat[0]).reshape(3, 3)
    com = np.array(data.subtree_com[1])
    # the reset's box and look-at point from the same state
    ours = camera_walk.start(jax.random.PRNGKey(0), settings, _f32(cam_pos), _f32(cam_mat), _f32(com), tracking)
    expected = _snapshot(ref)
    for field in ("low", "high", "velocity_scale", "lookat"):
        np.testing.assert_allclose(getattr(ours, field), getattr(expected, field), atol=ATOL, err_msg=field)
    for step in range(6):
        if step:
            env.step(rng.uniform(spec.minimum, spec.maximum))  # the physics moves the camera
        cam_pos, cam_mat = np.array(data.cam_xpos[0]), np.array(data.cam_xmat[0]).reshape(3, 3)
        com = np.array(data.subtree_com[1])
        before = _snapshot(ref)
        draws = copy.deepcopy(ref._random_state)  # the noise _apply is about to draw
        noise, roll_noise = draws.randn(3), draws.randn()
        ref._apply()
        walked = camera_walk.walk(before, settings, _f32(noise), _f32(roll_noise))
        after = _snapshot(ref)
        for field in ("sphere", "roll", "velocity", "roll_velocity"):
            np.testing.assert_allclose(getattr(walked, field), getattr(after, field), atol=ATOL,
                                       err_msg=f"{domain} step {step} {field}")
        position, rotation = camera_walk.pose(walked, settings, _f32(cam_pos), _f32(cam_mat), _f32(com), tracking)
        np.testing.assert_allclose(position, data.cam_xpos[0], atol=ATOL, err_msg=f"{domain} cam_xpos")
        np.testing.assert_allclose(rotation, np.reshape(data.cam_xmat[0], (3, 3)), atol=ATOL,
                                   err_msg=f"{domain} cam_xmat")
    if dynamic:
        assert np.linalg.norm(after.velocity) > 0, "the dynamic camera should move"
