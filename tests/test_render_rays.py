"""The camera's geometry against MuJoCo's own ray caster (``mujoco.mj_ray``).

For random poses of the six dm_control tasks (and a synthetic scene holding every supported
primitive), each pixel's ray is cast by ``mj_ray`` from the camera position along the same
direction; the hit geom must agree and the depth be within 1e-4 relative on at least 99.5% of
the pixels (the issue's bar). The directions themselves are checked against MuJoCo's own
mapping of a viewport point to a ray (``mjv_select``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from iap_mjx.render import Camera
from iap_mjx.viz.render_compare import TASKS, suite_states

VISIBLE_GROUPS = np.array([1, 1, 1, 0, 0, 0], np.uint8)
DEPTH_RTOL = 1e-4
MIN_AGREEMENT = 0.995

PRIMITIVES_XML = """
<mujoco>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1" directional="true"/>
    <geom type="plane" size="0 0 1" rgba=".2 .3 .4 1"/>
    <geom type="plane" size="1 .5 .1" pos="0 2 .5" zaxis="0 -1 .3" rgba=".5 .5 .1 1"/>
    <geom type="plane" size=".4 .3 .1" pos="-1.2 1.5 1.2" zaxis="0 -1 0" rgba=".5 .1 .1 1"/>
    <body name="a" pos="0 0 .6">
      <freejoint/>
      <geom type="sphere" size=".2" pos=".7 0 0" rgba="1 0 0 1"/>
      <geom type="capsule" size=".1 .3" pos="-.6 .2 0" euler="30 60 0" rgba="0 1 0 1"/>
      <geom type="ellipsoid" size=".3 .15 .1" pos="0 .6 .2" euler="10 20 30" rgba="0 0 1 1"/>
      <geom type="cylinder" size=".15 .25" pos="0 -.5 0" euler="80 10 0" rgba="1 1 0 1"/>
      <geom type="cylinder" size=".2 .05" pos=".6 .6 .3" rgba="1 0 1 1"/>
      <geom type="box" size=".2 .1 .3" pos="-.3 -.3 .4" euler="15 25 35" rgba="0 1 1 1"/>
      <geom type="box" size=".1 .1 .1" pos=".3 0 .7" rgba="1 1 1 0"/>
      <geom type="sphere" size=".1" pos="0 0 1" group="4" rgba="1 1 1 1"/>
    </body>
    <camera name="front" pos="0 -3 2" xyaxes="1 0 0 0 .6 .8" fovy="60"/>
    <camera name="above" pos=".3 .2 3.5" xyaxes="1 0 0 0 1 0" fovy="50"/>
  </worldbody>
</mujoco>
"""


# One compiled program per distinct camera (cameras hash by config and scene content).
_trace = jax.jit(Camera.trace, static_argnums=0)


def _mj_ray_image(model, data, cam: Camera):
    """``(H, W)`` depth and geom id from ``mj_ray`` through each pixel centre, with the far
    plane applied as our camera does (ids -1 and depth inf where nothing is hit)."""
    cam_id = cam.config.camera_id
    rot = data.cam_xmat[cam_id].reshape(3, 3)
    dirs = (cam.ray_directions().reshape(-1, 3).astype(np.float64)) @ rot.T
    origin = data.cam_xpos[cam_id].copy()
    depth = np.full(len(dirs), np.inf)
    ids = np.full(len(dirs), -1, np.int32)
    hit_id = np.zeros(1, np.int32)
    for i, direction in enumerate(dirs):
        dist = mujoco.mj_ray(model, data, origin, direction, VISIBLE_GROUPS, 1, -1, hit_id)
        if 0 <= dist < cam.zfar:
            depth[i], ids[i] = dist, hit_id[0]
    shape = (cam.config.height, cam.config.width)
    return depth.reshape(shape), ids.reshape(shape)


def _agreement(model, data, cam: Camera, mx_data=None) -> tuple[float, int]:
    """Fraction of pixels where the camera (on ``mx_data``, default: ``data`` moved to MJX)
    and ``mj_ray`` agree on the hit geom and the depth; and the number of hit pixels."""
    mx_data = mjx.put_data(model, data) if mx_data is None else mx_data
    depth, ids = (np.asarray(a) for a in _trace(cam, mx_data))
    ref_depth, ref_ids = _mj_ray_image(model, data, cam)
    hit = ref_ids >= 0
    ok = ids == ref_ids
    rel = np.abs(depth - np.where(hit, ref_depth, 0.0)) / np.where(hit, ref_depth, 1.0)
    ok &= np.where(hit, rel <= DEPTH_RTOL, depth == np.float32(cam.zfar))
    return float(ok.mean()), int(hit.sum())


@pytest.mark.parametrize("domain,task", TASKS)
def test_depth_and_geom_match_mj_ray_on_suite_tasks(domain, task):
    states = suite_states(domain, task, n_states=3, seed=7)
    for camera_id in range(states[0][0].ncam):
        for model, data in states:
            cam = Camera(model, camera_id=camera_id, height=60, width=80)
            agreement, n_hits = _agreement(model, data, cam)
            assert n_hits > 0, "the camera should see part of the scene"
            assert agreement >= MIN_AGREEMENT, (domain, camera_id, agreement)


def test_default_resolution_tracking_camera_after_mjx_forward():
    """The camera posed by MJX's own kinematics (cheetah's camera 0 tracks the body)."""
    ((model, data),) = suite_states("cheetah", "run", n_states=1, seed=3)
    cam = Camera(model)
    blank = mjx.put_data(model, mujoco.MjData(model))
    mx_data = jax.jit(mjx.forward)(mjx.put_model(model), blank.replace(qpos=jax.numpy.asarray(data.qpos)))
    agreement, _ = _agreement(model, data, cam, mx_data)
    assert agreement >= MIN_AGREEMENT


def test_every_primitive_matches_mj_ray():
    model = mujoco.MjModel.from_xml_string(PRIMITIVES_XML)
    rng = np.random.default_rng(0)
    seen = set()
    for camera_id in range(model.ncam):
        cam = Camera(model, camera_id=camera_id, height=64, width=64)
        for _ in range(3):
            data = mujoco.MjData(model)
            data.qpos[:3] = rng.uniform(-0.2, 0.2, 3) + np.array([0, 0, 0.6])
            quat = rng.normal(size=4)
            data.qpos[3:7] = quat / np.linalg.norm(quat) if rng.uniform() < 0.7 else [1, 0, 0, 0]
            mujoco.mj_forward(model, data)
            agreement, _ = _agreement(model, data, cam)
            assert agreement >= MIN_AGREEMENT, (camera_id, agreement)
            _, ref_ids = _mj_ray_image(model, data, cam)
            seen |= {int(model.geom_type[g]) for g in np.unique(ref_ids) if g >= 0}
    assert seen == {0, 2, 3, 4, 5, 6}, "every primitive type should be on screen at least once"


@pytest.mark.parametrize("cull_pairs_per_tile,overflows", [(0.02, True), (4.0, False)])
def test_tile_culling_and_its_fallback_equal_dense_tracing(cull_pairs_per_tile, overflows):
    """Culled tracing (and the dense fallback a chunk takes when a tile overflows its slots)
    gives the dense result (same geoms; depth to float rounding, as the culled formulas take
    sizes as arrays), one image at a time and under vmap with chunking."""
    states = suite_states("walker", "walk", n_states=3, seed=11)
    model = states[0][0]
    batch = jax.tree.map(lambda *x: np.stack(x), *[mjx.put_data(m, d) for m, d in states])
    dense = Camera(model, height=48, width=40, cull_pairs_per_tile=0)
    culled = Camera(model, height=48, width=40, cull_pairs_per_tile=cull_pairs_per_tile, batch_chunk=2, tile=8)
    assert culled.tracer.culled_groups, "walker's capsules should be culled"
    frames = jax.vmap(culled.tracer.geom_frames)(jax.vmap(culled.poses)(batch))
    _, overflow = jax.jit(jax.vmap(culled.tracer.culled_keys))(frames)
    assert bool(np.all(overflow)) == overflows, "the test should reach the intended path"
    want = jax.jit(jax.vmap(dense.trace))(batch)
    got = jax.jit(jax.vmap(culled.trace))(batch)
    single = jax.jit(culled.trace)(jax.tree.map(lambda x: x[0], batch))
    np.testing.assert_array_equal(np.asarray(want[1]), np.asarray(got[1]))
    np.testing.assert_array_equal(np.asarray(want[1])[0], np.asarray(single[1]))
    np.testing.assert_allclose(np.asarray(want[0]), np.asarray(got[0]), rtol=DEPTH_RTOL)
    np.testing.assert_allclose(np.asarray(want[0])[0], np.asarray(single[0]), rtol=DEPTH_RTOL)


def test_first_pairs_lists_the_first_true_entries_sorted():
    """``first_pairs`` against ``np.flatnonzero``: the first ``budget`` true entries in order,
    the valid mask, and a list that stays sorted through its empty slots (the tile scatter
    is told its indices are sorted)."""
    from iap_mjx.render.tracing import first_pairs

    rng = np.random.default_rng(0)
    first_pairs = jax.jit(first_pairs, static_argnums=1)
    for n, budget, density in ((700, 64, 0.05), (700, 16, 0.05), (97, 40, 0.2), (128, 8, 0.0)):
        overlap = rng.uniform(size=n) < density
        pair, valid = (np.asarray(a) for a in first_pairs(jnp.asarray(overlap), budget))
        want = np.flatnonzero(overlap)[:budget]
        np.testing.assert_array_equal(valid, np.arange(budget) < len(want))
        np.testing.assert_array_equal(pair[valid], want)
        assert np.all(np.diff(pair) >= 0), (n, budget, pair)


LIGHTS_XML = """
<mujoco>
  <worldbody>
    <light name="world" pos="0 0 3" dir="0 .3 -1"/>
    <body name="arm" pos=".2 0 1">
      <joint type="ball"/>
      <geom type="capsule" size=".05 .3" fromto="0 0 0 .6 0 0" mass="1"/>
      <light name="fixed" mode="fixed" pos=".1 .2 .3" dir="1 0 -1"/>
      <light name="track" mode="track" pos=".1 .2 .3" dir="0 1 -1"/>
      <light name="trackcom" mode="trackcom" pos=".1 .2 .3" dir="1 1 -1"/>
      <light name="target" mode="targetbody" target="hand" pos="0 .2 .3" dir="0 0 -1"/>
      <light name="targetcom" mode="targetbodycom" target="arm" pos=".2 0 .5" dir="0 0 -1"/>
      <light name="no_target" mode="targetbody" pos="-.1 0 .2" dir="0 1 0"/>
      <body name="hand" pos=".6 0 0">
        <joint type="hinge" axis="0 1 0"/>
        <geom type="sphere" size=".1" mass=".5"/>
      </body>
    </body>
    <camera pos="0 -3 1.5" xyaxes="1 0 0 0 .5 1"/>
  </worldbody>
</mujoco>
"""


def test_lights_are_placed_as_mj_camlight_places_them():
    """Every light mode (fixed, tracking the body or its subtree's centre of mass, aimed at a
    target body or its subtree's centre of mass, a target mode without a target) at random
    poses: the camera's light positions and directions are MuJoCo's ``light_xpos`` and
    ``light_xdir`` (from ``mj_forward``), in the camera frame."""
    model = mujoco.MjModel.from_xml_string(LIGHTS_XML)
    cam = Camera(model)
    rng = np.random.default_rng(0)
    for _ in range(3):
        data = mujoco.MjData(model)
        quat = rng.normal(size=4)
        data.qpos[:] = np.concatenate([quat / np.linalg.norm(quat), rng.uniform(-1, 1, 1)])
        mujoco.mj_forward(model, data)
        position, direction = (
            np.asarray(a) for a in cam.shader.lights_in_camera_frame(cam.poses(mjx.put_data(model, data)))
        )
        rot = data.cam_xmat[0].reshape(3, 3)
        np.testing.assert_allclose(position, (data.light_xpos - data.cam_xpos[0]) @ rot, atol=1e-5)
        np.testing.assert_allclose(direction, data.light_xdir @ rot, atol=1e-5)


def test_pixel_rays_are_mujocos_own_through_each_pixel_centre():
    """Each pixel's ray direction (field of view, aspect, half-pixel centre, image rows from
    the top) against MuJoCo's own mapping of a viewport point to a ray (``mjv_select`` on the
    scene ``mjv_updateScene`` builds for the fixed camera, through the hit point it returns),
    on a 24x32 image from both cameras of the primitives scene. The angle between them is
    float32 rounding of a unit vector (a few ulps; bound 16 ulps), where a ray through a
    pixel's corner instead of its centre is half a pixel (~0.02 rad) off: checked to fail."""
    model = mujoco.MjModel.from_xml_string(PRIMITIVES_XML)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    height, width = 24, 32
    bound = 16 * float(np.finfo(np.float32).eps)
    option, scene = mujoco.MjvOption(), mujoco.MjvScene(model, 1000)
    for camera_id in range(model.ncam):
        view = mujoco.MjvCamera()
        view.type, view.fixedcamid = mujoco.mjtCamera.mjCAMERA_FIXED, camera_id
        mujoco.mjv_updateScene(model, data, option, None, view, mujoco.mjtCatBit.mjCAT_ALL, scene)
        cam = Camera(model, camera_id=camera_id, height=height, width=width)
        ours = (
            np.asarray(cam.ray_directions(), np.float64).reshape(height, width, 3)
            @ data.cam_xmat[camera_id].reshape(3, 3).T
        )
        ours /= np.linalg.norm(ours, axis=-1, keepdims=True)

        def mujoco_ray(x: float, y: float) -> np.ndarray:
            """MuJoCo's unit ray through the viewport point (x, y) (fractions of the width and
            height from the bottom-left corner), from the camera to what it hits."""
            point, ids = np.zeros(3), [np.full(1, -1, np.int32) for _ in range(3)]
            mujoco.mjv_select(model, data, option, width / height, x, y, scene, point, *ids)
            assert ids[0][0] >= 0, "every pixel of the scene hits a geom (the planes)"
            ray = point - data.cam_xpos[camera_id]
            return ray / np.linalg.norm(ray)

        def largest_angle(offset: float) -> float:
            return max(
                float(
                    np.arccos(np.clip(mujoco_ray((j + offset) / width, 1 - (i + offset) / height) @ ours[i, j], -1, 1))
                )
                for i in range(height)
                for j in range(width)
            )

        assert largest_angle(0.5) <= bound, (camera_id, largest_angle(0.5), bound)
        assert largest_angle(0.0) > 100 * bound, camera_id  # the corner, not the centre
