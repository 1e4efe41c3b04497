"""The sky as MuJoCo's renderer draws a skybox texture, and partly transparent geoms over it.

A skybox is a cube around the camera, seen by ray direction only. The Distracting Control
Suite replaces the skybox texture by one square video frame, which MuJoCo then repeats on
all six faces (a cube texture whose height equals its width). Each face's orientation was
measured with ``mujoco.Renderer`` (a test texture encoding row and column, rendered in
random directions; ``tests/test_render_sky.py`` keeps checking it): for a world direction
``d`` whose largest component is the face's axis, the texture is read at

====== ================ =================
face    column from      row from
====== ================ =================
 +x     ``+d_y / d_x``   ``-d_z / |d_x|``
 -x     ``-d_y / |d_x|`` ``-d_z / |d_x|``
 +y     ``-d_x / d_y``   ``-d_z / d_y``
 -y     ``+d_x / |d_y|`` ``-d_z / |d_y|``
 +z     ``+d_x / d_z``   ``-d_y / d_z``
 -z     ``+d_x / |d_z|`` ``+d_y / |d_z|``
====== ================ =================

each ratio in [-1, 1] mapped to [0, S) texels (row 0 is the frame's top: on the side
faces the frame stands upright). Texels are read nearest (MuJoCo filters linearly; the
difference is at most a texel's blur).

Everything here works on planes ``(H, W)`` with an optional leading axis of images, so the
camera can call it on a chunk of images at once: the texture read is then one gather from
a stack of textures, one row per image, which XLA:CPU runs faster than a batched gather.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def pack_rgb(texture: jax.Array) -> jax.Array:
    """``(..., S, S, 3)`` uint8 -> ``(..., S * S)`` int32 texels ``r | g << 8 | b << 16``
    (one gather per pixel reads all three channels)."""
    t = texture.astype(jnp.int32)
    packed = t[..., 0] | (t[..., 1] << 8) | (t[..., 2] << 16)
    return packed.reshape(packed.shape[:-2] + (-1,))


def face_texel(dx: jax.Array, dy: jax.Array, dz: jax.Array, size: int) -> jax.Array:
    """Index ``row * size + col`` (int32, the shape of ``dx``) of the texel MuJoCo's skybox
    shows in world direction ``(dx, dy, dz)`` (any length), for a ``size x size`` face
    repeated on the cube (table in the module docstring)."""
    ax, ay, az = jnp.abs(dx), jnp.abs(dy), jnp.abs(dz)
    x_major = (ax >= ay) & (ax >= az)
    y_major = ~x_major & (ay >= az)
    major = jnp.where(x_major, ax, jnp.where(y_major, ay, az))
    across = jnp.where(x_major, jnp.where(dx > 0, dy, -dy), jnp.where(y_major, jnp.where(dy > 0, -dx, dx), dx))
    down = jnp.where(x_major | y_major, -dz, jnp.where(dz > 0, -dy, dy))
    half = 0.5 * size
    scale = half / jnp.maximum(major, 1e-30)
    col = jnp.floor(jnp.clip(across * scale + half, 0.0, size - 1.0))
    row = jnp.floor(jnp.clip(down * scale + half, 0.0, size - 1.0))
    # float until the end: CPU loops that mix int32 into float math do not vectorise
    return (row * size + col).astype(jnp.int32)


def skybox_texels(
    packed: jax.Array, frame: jax.Array, size: int, dx: jax.Array, dy: jax.Array, dz: jax.Array
) -> jax.Array:
    """``(..., H, W)`` int32 packed texels (:func:`pack_rgb`) of the skybox textures
    ``packed[frame]`` (``packed``: ``(N, S * S)`` textures; ``frame``: ``(...)`` int32, one row
    per image) in world directions ``dx, dy, dz`` ``(..., H, W)``, as one flat gather from
    the stack; :func:`unpack_rgb` gives the colours."""
    index = face_texel(dx, dy, dz, size)
    offsets = (frame * packed.shape[1]).reshape(jnp.shape(frame) + (1,) * (index.ndim - jnp.ndim(frame)))
    return packed.reshape(-1).at[index + offsets].get(mode="promise_in_bounds")


def unpack_rgb(texel: jax.Array) -> list[jax.Array]:
    """``[3 x (...)]`` float32 colours in [0, 1] of packed texels (:func:`pack_rgb`)."""
    return [((texel >> (8 * c)) & 255).astype(jnp.float32) * (1.0 / 255.0) for c in range(3)]


def over(alpha: jax.Array, front: jax.Array, behind: jax.Array) -> jax.Array:
    """A partly transparent surface ``front`` with opacity ``alpha`` drawn over ``behind``
    (MuJoCo's blending of transparent geoms: ``alpha * front + (1 - alpha) * behind``)."""
    return behind + alpha * (front - behind)
