"""The skybox texel seen in each direction (``iap_mjx.render.sky.face_texel``) against MuJoCo's
renderer: a 16x16 texture encoding its own column (red) and row (green) uploaded as the
skybox (square, so MuJoCo repeats it on all six cube faces, as the Distracting Control
Suite's background frames are), rendered by ``mujoco.Renderer`` from 36 camera orientations
(six per cube face, each within 0.35 rad of the face's axis) with every material made
invisible; at each pixel where MuJoCo shows the sky, the (row, column) it decodes must be the
one ``face_texel`` gives for that pixel's ray.

Measure: MuJoCo filters the texture linearly, so a decoded coordinate is off by up to half a
texel near texel edges (and the horizon's haze shifts a few): per face, the median absolute
difference <= 0.5 texel and the 90th percentile <= 1.0. A mirrored or transposed face is off
by up to 15 texels (median ~5).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mujoco import mjx

from iap_mjx.render import Camera, sky
from iap_mjx.viz import render_compare

SIZE = 16
HEIGHT, WIDTH = 24, 32
AXES = ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))


def _look(direction):
    """A camera frame (columns: camera x, y, z in the world) looking along ``direction``."""
    z = -direction / np.linalg.norm(direction)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def test_skybox_texels_match_mujoco_by_direction():
    rng = np.random.default_rng(0)
    ((model, data),) = render_compare.suite_states("cartpole", "swingup", n_states=1, seed=0)
    mats, faces = [], []
    for face, axis in enumerate(AXES):
        for _ in range(6):
            mats.append(_look(np.asarray(axis, float) + rng.uniform(-0.35, 0.35, 3)))
            faces.append(face)
    mats = np.stack(mats)
    n = len(mats)
    col, row = np.meshgrid(np.arange(SIZE), np.arange(SIZE))
    texture = np.stack([col * 16 + 8, row * 16 + 8, np.full_like(col, 128)], -1).astype(np.uint8)
    rgba = np.array(model.mat_rgba)
    rgba[:, 3] = 0.0  # every material invisible: more sky
    edits = {
        "mat_rgba": np.stack([rgba] * n),
        "sky": np.stack([texture] * n),
        "cam_xpos": np.tile(np.asarray(data.cam_xpos[0], np.float64), (n, 1)),
        "cam_xmat": mats,
    }
    ref = render_compare.reference_frames("cartpole", [(model, data)] * n, [0], HEIGHT, WIDTH, distractions=edits)
    rays = Camera(model, height=HEIGHT, width=WIDTH).ray_directions()  # (H, W, 3), camera frame
    world = np.einsum("nij,hwj->nhwi", mats, rays).astype(np.float32)
    texel = np.asarray(jax.jit(lambda d: sky.face_texel(d[..., 0], d[..., 1], d[..., 2], SIZE))(world))
    rgb = ref["rgb"][:, 0].astype(np.float64)
    seen_sky = ref["segmentation"][:, 0] < 0
    decoded_col, decoded_row = (rgb[..., 0] - 8) / 16, (rgb[..., 1] - 8) / 16
    for face in range(6):
        mask = seen_sky & (np.asarray(faces) == face)[:, None, None]
        assert mask.sum() > 500, (face, mask.sum())
        error = np.concatenate([np.abs(decoded_col - texel % SIZE)[mask], np.abs(decoded_row - texel // SIZE)[mask]])
        assert np.median(error) <= 0.5 and np.percentile(error, 90) <= 1.0, (
            AXES[face],
            np.median(error),
            np.percentile(error, 90),
        )


def test_a_sky_stack_and_row_draw_the_same_frame_as_the_frame_itself():
    """``sky_texture=(stack, row)`` (the distraction layer's form: its whole frame stack,
    shared by the batch and read in place) draws exactly what passing the selected frame
    itself draws, under ``vmap`` and for one image; a row that is not a scalar is refused."""
    states = render_compare.suite_states("cartpole", "swingup", n_states=3, seed=3)
    model = states[0][0]
    batch = jax.tree.map(lambda *x: np.stack(x), *[mjx.put_data(m, d) for m, d in states])
    rng = np.random.default_rng(1)
    frames = rng.integers(0, 256, (5, SIZE, SIZE, 3), dtype=np.uint8)
    stack = sky.pack_rgb(jnp.asarray(frames))  # (5, S * S)
    rows = jnp.asarray([4, 0, 2], jnp.int32)
    cam = Camera(model, height=12, width=16, batch_chunk=2)
    want = jax.jit(jax.vmap(lambda d, f: cam.render(d, sky_texture=f)))(batch, jnp.asarray(frames)[rows])
    draw = jax.jit(jax.vmap(lambda d, r: cam.render(d, sky_texture=(stack, r))))
    got = draw(batch, rows)
    one = jax.jit(lambda d: cam.render(d, sky_texture=(stack, rows[0])))(jax.tree.map(lambda x: x[0], batch))
    for w, g in zip(want, got):
        np.testing.assert_array_equal(np.asarray(w), np.asarray(g))
    np.testing.assert_array_equal(np.asarray(want[0][0]), np.asarray(one[0]))
    other = draw(batch, (rows + 1) % len(frames))
    assert not np.allclose(np.asarray(got[0]), np.asarray(other[0])), "the sky should be on screen"
    with pytest.raises(ValueError, match="row must be a scalar"):
        cam.render(jax.tree.map(lambda x: x[0], batch), sky_texture=(stack, rows))
