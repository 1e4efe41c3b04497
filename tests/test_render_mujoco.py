"""The camera against MuJoCo's own OpenGL renderer (``mujoco.Renderer``, software OSMesa).

Same camera, same state: the geom covering each pixel (MuJoCo's segmentation render) agrees
with ours on at least 97% of the pixels (the issue's bar), and where both see the same geom
the depths agree (MuJoCo's depth buffer is linearised from 24-bit z, hence the loose bound).
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
from mujoco import mjx

from iap_mjx.render import Camera
from iap_mjx.viz import render_compare

SIZE = 64
MIN_SEGMENTATION_AGREEMENT = 0.97
_trace = jax.jit(Camera.trace, static_argnums=0)


@pytest.mark.parametrize("domain,task", render_compare.TASKS)
def test_segmentation_matches_mujoco_renderer(domain, task):
    states = render_compare.suite_states(domain, task, n_states=2, seed=5)
    cameras = list(range(states[0][0].ncam))
    ref = render_compare.reference_frames(domain, states, cameras, SIZE, SIZE)
    for i, (model, data) in enumerate(states):
        for camera_id in cameras:
            cam = Camera(model, camera_id=camera_id, height=SIZE, width=SIZE)
            depth, ids = (np.asarray(a) for a in _trace(cam, mjx.put_data(model, data)))
            ref_ids = ref["segmentation"][i, camera_id]
            agreement = float(np.mean(ids == ref_ids))
            assert agreement >= MIN_SEGMENTATION_AGREEMENT, (domain, camera_id, agreement)
            both = (ids == ref_ids) & (ids >= 0)
            ref_depth = ref["depth"][i, camera_id][both]
            rel = np.abs(depth[both] - ref_depth) / ref_depth
            assert np.median(rel) < 1e-3, (domain, camera_id, np.median(rel))


CHECKER_XML = """
<mujoco>
  <visual><headlight ambient="1 1 1" diffuse="0 0 0" specular="0 0 0"/></visual>
  <asset>
    <texture name="checker" type="2d" builtin="checker" rgb1="1 1 1" rgb2="0 0 0" width="64" height="64"/>
    <material name="uniform" texture="checker" texrepeat="2 3" texuniform="true" specular="0" reflectance="0"/>
    <material name="spread" texture="checker" texrepeat="1.5 2.5" specular="0" reflectance="0"/>
    <material name="spread_int" texture="checker" texrepeat="1 2" specular="0" reflectance="0"/>
    <material name="half_infinite" texture="checker" texrepeat="1.3 .6" specular="0" reflectance="0"/>
  </asset>
  <worldbody>
    <geom type="plane" size="1.5 1.2 .1" euler="0 0 30" material="uniform"/>
    <geom type="plane" size="1.4 1.2 .1" pos="5 0 0" material="spread"/>
    <geom type="plane" size="1.3 .8 .1" pos="10 .2 0" euler="0 0 20" material="spread_int"/>
    <geom type="plane" size="0 1.1 .1" pos="0 10 0" material="half_infinite"/>
    <camera pos=".13 .07 2" xyaxes="1 0 0 0 1 0" fovy="60"/>
    <camera pos="5 0 2" xyaxes="1 0 0 0 1 0" fovy="60"/>
    <camera pos="10 .2 2" xyaxes="1 0 0 0 1 0" fovy="60"/>
    <camera pos="3 10.1 2" xyaxes="1 0 0 0 1 0" fovy="60"/>
  </worldbody>
</mujoco>
"""


def test_checker_floor_matches_mujoco_renderer():
    """A black-and-white checker texture on planes with and without ``texuniform``, integer
    and fractional ``texrepeat``, rotated, moved and half-infinite, seen from above with only
    an ambient headlight (so MuJoCo's pixel is the texture): on the planes, our checker
    square colour is MuJoCo's on at least 97% of the pixels (the misses are at square edges,
    which MuJoCo filters). The control: our checker with twice the texture repeats (squares
    half as long) agrees with MuJoCo's on at most 60% of them, so the bar tells a right
    checker from a wrong one."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(CHECKER_XML)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    denser = mujoco.MjModel.from_xml_string(CHECKER_XML)
    denser.mat_texrepeat *= 2
    cameras = list(range(model.ncam))
    ref = render_compare.reference_frames("checker", [(model, data)], cameras, SIZE, SIZE, xml=CHECKER_XML)
    for camera_id in cameras:
        plane = ref["segmentation"][0, camera_id] >= 0
        assert plane.mean() > 0.5, camera_id
        mujoco_white = ref["rgb"][0, camera_id][..., 0] > 127
        agreement = {}
        for name, rendered in (("same", model), ("denser", denser)):
            cam = Camera(rendered, camera_id=camera_id, height=SIZE, width=SIZE, shading="flat")
            rgb, _ = jax.jit(cam.render)(mjx.put_data(rendered, data))
            ours_white = np.asarray(rgb)[..., 0] > 0.5
            agreement[name] = float(np.mean((ours_white == mujoco_white)[plane]))
        assert agreement["same"] >= 0.97, (camera_id, agreement)
        assert agreement["denser"] <= 0.6, (camera_id, agreement)


ALPHA_XML = """
<mujoco>
  <asset>
    <material name="opaque" rgba="0 1 0 1"/>
    <material name="clear" rgba="0 1 0 0"/>
  </asset>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1" directional="true"/>
    <geom type="plane" size="0 0 1" rgba=".2 .3 .4 1"/>
    <geom type="box" size=".3 .3 .3" pos="-.4 0 .3" rgba="1 0 0 1"/>
    <geom type="box" size=".3 .3 .3" pos=".4 0 .3" rgba="0 0 1 1"/>
    <geom name="hidden" type="box" size=".2 .2 .2" pos="-.4 -1 .5" material="opaque" rgba="1 1 0 0"/>
    <geom name="shown" type="box" size=".2 .2 .2" pos=".4 -1 .5" material="clear" rgba="1 1 0 1"/>
    <camera pos="0 -3 1.5" xyaxes="1 0 0 0 .5 1" fovy="45"/>
  </worldbody>
</mujoco>
"""


def test_geom_visibility_follows_the_colour_mujoco_draws():
    """A geom is drawn unless the rgba MuJoCo's renderer gives it (the material's only while
    the geom keeps the default rgba) has alpha 0: a geom of rgba alpha 0 with an opaque
    material is not drawn, one of rgba alpha 1 with a clear material is (``mj_ray`` tests
    the material's alpha alone, and sees the other way round). Segmentation against MuJoCo's
    renderer."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(ALPHA_XML)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    ref = render_compare.reference_frames("alpha", [(model, data)], [0], SIZE, SIZE, xml=ALPHA_XML)
    cam = Camera(model, height=SIZE, width=SIZE)
    _, ids = (np.asarray(a) for a in _trace(cam, mjx.put_data(model, data)))
    ref_ids = ref["segmentation"][0, 0]
    hidden, shown = (mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in ("hidden", "shown"))
    assert np.sum(ref_ids == shown) > 50 and not np.any(ref_ids == hidden)
    assert float(np.mean(ids == ref_ids)) >= MIN_SEGMENTATION_AGREEMENT
