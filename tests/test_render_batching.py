"""``Camera.render`` gives the same images one at a time, under ``vmap`` (chunked by the
camera's batching rule, with a batch that is not a multiple of the chunk) and under nested
``vmap`` (as a population x episodes rollout calls it); and it validates its inputs."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mujoco import mjx

from iap_mjx.render import Camera
from iap_mjx.viz import render_compare


def test_single_vmap_and_nested_vmap_agree():
    states = render_compare.suite_states("walker", "walk", n_states=6, seed=0)
    model = states[0][0]
    batch = jax.tree.map(lambda *x: jnp.stack(x), *[mjx.put_data(m, d) for m, d in states])
    cam = Camera(model, height=40, width=48, batch_chunk=4)
    flat_rgb, flat_depth = jax.jit(jax.vmap(cam.render))(batch)
    grid = jax.tree.map(lambda x: x.reshape((2, 3) + x.shape[1:]), batch)
    nested_rgb, nested_depth = jax.jit(jax.vmap(jax.vmap(cam.render)))(grid)
    assert flat_rgb.shape == (6, 40, 48, 3) and flat_depth.shape == (6, 40, 48)
    assert flat_rgb.dtype == jnp.float32 and flat_depth.dtype == jnp.float32
    np.testing.assert_allclose(nested_rgb.reshape(flat_rgb.shape), flat_rgb, atol=1e-5)
    np.testing.assert_allclose(nested_depth.reshape(flat_depth.shape), flat_depth, rtol=1e-6)
    render = jax.jit(cam.render)
    for i in (0, 5):
        rgb, depth = render(jax.tree.map(lambda x: x[i], batch))
        np.testing.assert_allclose(rgb, flat_rgb[i], atol=1e-5)
        np.testing.assert_allclose(depth, flat_depth[i], rtol=1e-6)
    assert 0.0 <= float(flat_rgb.min()) and float(flat_rgb.max()) <= 1.0


def test_background_image_replaces_the_sky_and_config_is_validated():
    ((model, data),) = render_compare.suite_states("cartpole", "swingup", n_states=1, seed=0)
    cam = Camera(model, height=24, width=32)
    mx_data = mjx.put_data(model, data)
    _, ids = cam.trace(mx_data)
    background = jnp.full((24, 32, 3), 0.25, jnp.float32).at[:, :, 1].set(0.75)
    rgb, depth = cam.render(mx_data, background=background)
    sky = np.asarray(ids) < 0
    assert sky.any(), "part of the image should be sky"
    np.testing.assert_allclose(np.asarray(rgb)[sky], np.asarray(background)[sky])
    np.testing.assert_allclose(np.asarray(depth)[sky], cam.zfar)
    with pytest.raises(ValueError, match="background"):
        cam.render(mx_data, background=jnp.zeros((3, 3, 3)))
    with pytest.raises(ValueError, match="shading"):
        Camera(model, shading="phong")
    with pytest.raises(ValueError, match="camera_id"):
        Camera(model, camera_id=model.ncam)
    for name in ("height", "width", "tile", "batch_chunk"):  # a bool is not a size
        with pytest.raises(ValueError, match=f"{name} must be an int >= 1"):
            Camera(model, **{name: True})
    assert hash(Camera(model, height=24, width=32)) == hash(cam)
    assert Camera(model, height=24, width=32) == cam


def test_a_non_finite_pose_blanks_its_own_image_only():
    """Under ``vmap`` (chunks of 2), images whose camera pose is NaN or inf see nothing (depth
    at the far plane, id -1, black), and the finite images of the same chunks are drawn as
    they are alone; a chunk with no finite pose too. With a skybox texture, whose lookup by
    ray direction must not read outside the texture for a non-finite pose."""
    states = render_compare.suite_states("walker", "walk", n_states=6, seed=1)
    model = states[0][0]
    batch = jax.tree.map(lambda *x: jnp.stack(x), *[mjx.put_data(m, d) for m, d in states])
    bad = (1, 2, 3, 4)  # chunks: (good, bad), (bad, bad), (bad, good)
    cam_xpos = batch.cam_xpos.at[1].set(jnp.nan).at[3, :, 0].set(jnp.inf)
    cam_xmat = batch.cam_xmat.at[2].set(jnp.nan).at[4, :, 1, 1].set(-jnp.inf)
    batch = batch.replace(cam_xpos=cam_xpos, cam_xmat=cam_xmat)
    sky = jnp.asarray(np.random.default_rng(0).integers(0, 256, (8, 8, 3), dtype=np.uint8))
    cam = Camera(model, height=20, width=24, batch_chunk=2)
    render = lambda d: cam.render_ids(d, sky_texture=sky)  # noqa: E731
    rgb, depth, ids = (np.asarray(a) for a in jax.jit(jax.vmap(render))(batch))
    for i in bad:
        assert np.all(rgb[i] == 0.0) and np.all(depth[i] == np.float32(cam.zfar)) and np.all(ids[i] == -1), i
    single = jax.jit(render)
    for i in (0, 5):
        want = single(jax.tree.map(lambda x: x[i], batch))
        assert (np.asarray(want[2]) >= 0).any(), "the walker should be on screen"
        np.testing.assert_allclose(rgb[i], want[0], atol=1e-5)
        np.testing.assert_allclose(depth[i], want[1], rtol=1e-6)
        np.testing.assert_array_equal(ids[i], want[2])


@pytest.mark.parametrize(
    "camera, height, width, match",
    [
        ('projection="orthographic" fovy="2"', 48, 64, "only perspective cameras"),
        ('focal=".01 .01" sensorsize=".02 .015" resolution="64 48"', 48, 48, "width / height equal to the sensor"),
        ('focal=".01 .012" sensorsize=".02 .015" resolution="64 48"', 48, 64, "equal focal lengths"),
        ('focal=".01 .01" principal=".001 0" sensorsize=".02 .015" resolution="64 48"', 48, 64, "principal"),
    ],
)
def test_cameras_drawn_otherwise_by_mujoco_are_refused(camera, height, width, match):
    """An orthographic camera, or intrinsics whose frustum is not the ``cam_fovy`` one at the
    image's aspect ratio, would be drawn differently from MuJoCo's renderer: a clear error
    before anything compiles (a sensor of the image's aspect ratio is accepted)."""
    import mujoco

    xml = f'<mujoco><worldbody><geom type="sphere" size=".1"/><camera pos="0 0 2" {camera}/></worldbody></mujoco>'
    model = mujoco.MjModel.from_xml_string(xml)
    with pytest.raises(ValueError, match=match):
        Camera(model, height=height, width=width)
    if "sensorsize" in camera and "principal" not in camera and '".01 .01"' in camera:
        Camera(model, height=48, width=64)


def test_bad_settings_and_inputs_are_refused_with_the_setting_named():
    ((model, data),) = render_compare.suite_states("cartpole", "swingup", n_states=1, seed=0)
    cam = Camera(model, height=24, width=32)
    with pytest.raises(ValueError, match="background must be floats"):
        cam.render(mjx.put_data(model, data), background=jnp.zeros((24, 32, 3), jnp.uint8))
    for setting, value in (
        ("cull_pairs_per_tile", float("nan")),
        ("cull_pairs_per_tile", float("inf")),
        ("geom_groups", 1),
        ("background_color", (0.0, 0.5, 255.0)),
    ):
        with pytest.raises(ValueError, match=setting):
            Camera(model, **{setting: value})


def test_a_sky_row_outside_the_stack_is_clamped():
    """``sky_texture=(stack, row)`` with a row past either end draws the end row (the texel
    gather trusts its indices: unclamped, it would read outside the stack)."""
    from iap_mjx.render import sky

    ((model, data),) = render_compare.suite_states("cartpole", "swingup", n_states=1, seed=0)
    frames = np.random.default_rng(2).integers(0, 256, (3, 8, 8, 3), dtype=np.uint8)
    stack = sky.pack_rgb(jnp.asarray(frames))
    cam = Camera(model, height=12, width=16)
    draw = jax.jit(lambda d, r: cam.render(d, sky_texture=(stack, r))[0])
    mx_data = mjx.put_data(model, data)
    first, last = (np.asarray(draw(mx_data, jnp.int32(r))) for r in (0, 2))
    assert not np.array_equal(first, last), "the sky should be on screen"
    np.testing.assert_array_equal(np.asarray(draw(mx_data, jnp.int32(-5))), first)
    np.testing.assert_array_equal(np.asarray(draw(mx_data, jnp.int32(1000))), last)
