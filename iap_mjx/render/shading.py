"""The camera's colour pass: from each pixel's depth and nearest geom to RGB.

Shading needs no per-geom work per pixel: the colour is looked up by geom index
(:meth:`Shader.surface_colour`), Lambert normals come from the hit points of neighbouring
pixels on the same geom (:meth:`Shader.incident_light`), the floor checker from the plane's hit
coordinates, the sky from the ray's elevation (:meth:`Shader.sky_gradient`) or a skybox texture
by ray direction (:meth:`Shader.skybox_texels`, ``sky.py``), and partly transparent geoms are
blended over it (:meth:`Shader.compose`). Colours are kept as three ``(H, W)`` planes, never an
interleaved ``(H, W, 3)`` array, until the camera stacks the result.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from iap_mjx.render import scene as scene_lib
from iap_mjx.render import sky as sky_lib
from iap_mjx.render.tracing import GeomFrames, Poses

if TYPE_CHECKING:  # camera.py imports this module
    from iap_mjx.render.camera import CameraConfig


class Shader:
    """Colours, lights and sky of one camera's scene; its methods are pure functions of one
    image (``vmap`` them for a batch) except :meth:`skybox_texels`, which takes a chunk.

    ``padded`` arguments are the trace's depth and geom index with a one-pixel border
    (``tracing.pad_by_one_pixel``), both ``(H + 2, W + 2)`` float32; ``poses`` are the
    per-state arrays the camera reads (``Camera.poses``, :class:`~iap_mjx.render.tracing.Poses`);
    ``frames`` are ``Tracer.geom_frames``'s (:class:`~iap_mjx.render.tracing.GeomFrames`)."""

    def __init__(
        self,
        scene: scene_lib.Scene,
        config: CameraConfig,
        x: np.ndarray,
        y: np.ndarray,
        pixel_pitch: tuple[float, float],
    ):
        """``config``: the camera's ``CameraConfig``; ``x`` ``(1, W)``, ``y`` ``(H, 1)``: the
        pixels' image coordinates and ``pixel_pitch`` their spacing (``Tracer``'s)."""
        self.scene = scene
        self.config = config
        self.x, self.y = x, y
        self.pixel_pitch = pixel_pitch

    def compose(
        self,
        poses: Poses,
        surface: Sequence[jax.Array],
        light: Sequence[jax.Array],
        best_p: jax.Array,
        background: jax.Array | tuple[jax.Array, ...] | list[jax.Array],
    ) -> tuple[jax.Array, ...]:
        """``3 x (H, W)`` float32 image planes: lit surface where a geom is hit, else the
        background.

        ``surface``: ``3 x (H, W)`` colours (:meth:`surface_colour`); ``light``: ``1 x (H, W)``
        or ``3 x (H, W)`` (:meth:`incident_light`); ``best_p``: ``(H + 2, W + 2)`` the padded
        float geom index of ``tracing.pad_by_one_pixel``; ``background``: ``3 x (H, W)`` planes
        (:meth:`skybox_texels`' colours), an ``(H, W, 3)`` float image, or an empty array for
        the sky (:meth:`sky_gradient` from ``poses["cam_mat"]``)."""
        best = best_p[1:-1, 1:-1]
        if isinstance(background, (tuple, list)):  # the skybox planes of ``skybox_texels``
            background = list(background)
        elif background.size == 0:
            background = self.sky_gradient(poses["cam_mat"])
        else:
            background = [background[..., c].astype(jnp.float32) for c in range(3)]
        hit = best < len(self.scene.geom_ids)
        light = [light[min(c, len(light) - 1)] for c in range(3)]
        lit = [jnp.clip(surface[c] * light[c], 0.0, 1.0) for c in range(3)]
        transparent = np.flatnonzero(self.scene.geom_alpha < 1.0)
        if transparent.size:
            alpha = jnp.ones_like(best)
            for k in transparent:
                alpha = jnp.where(best == k, float(self.scene.geom_alpha[k]), alpha)
            lit = [sky_lib.over(alpha, lit[c], background[c]) for c in range(3)]
        return tuple(jnp.where(hit, lit[c], background[c]) for c in range(3))

    def skybox_texels(self, cam_mat: jax.Array, sky_texture: jax.Array, sky_frame: jax.Array) -> jax.Array:
        """``([C,] H, W)`` int32 packed texels of frame ``sky_frame`` ``([C])`` of the stack
        ``sky_texture`` (``(N, S * S)`` shared, or ``(C, N, S * S)`` one stack per image) by
        world ray direction (``cam_mat`` ``([C,] 3, 3)``): one gather for a whole chunk."""
        if sky_texture.ndim == 3:  # one stack per image: rows of the stacks laid end to end
            n = sky_texture.shape[1]
            sky_frame = jnp.arange(sky_texture.shape[0], dtype=jnp.int32) * n + sky_frame
            sky_texture = sky_texture.reshape(-1, sky_texture.shape[-1])
        x = jnp.asarray(self.x)
        y = jnp.asarray(self.y)
        m = cam_mat[..., None, None]  # (..., 3, 3, 1, 1) against (H, 1) and (1, W)
        dx, dy, dz = (x * m[..., i, 0, :, :] + y * m[..., i, 1, :, :] - m[..., i, 2, :, :] for i in range(3))
        size = math.isqrt(int(sky_texture.shape[-1]))
        return sky_lib.skybox_texels(sky_texture, sky_frame, size, dx, dy, dz)

    def surface_colour(
        self, frames: GeomFrames, padded: tuple[jax.Array, jax.Array], geom_rgb: jax.Array
    ) -> tuple[jax.Array, ...]:
        """Surface colour ``3 x (H, W)`` float32 of each pixel's nearest geom (``0`` where none
        is hit): the geom's, or the checker floor's at the hit point. ``geom_rgb``: ``(G, 3)``
        colours replacing the model's, or empty (``(0,)``)."""
        rgb_table = self.scene.geom_rgb if geom_rgb.size == 0 else geom_rgb.astype(jnp.float32)
        sc = self.scene
        depth_p, best_p = padded
        depth, best = depth_p[1:-1, 1:-1], best_p[1:-1, 1:-1]
        x, y = jnp.asarray(self.x), jnp.asarray(self.y)
        colour = [jnp.zeros_like(depth) for _ in range(3)]
        for geom in range(len(sc.geom_ids)):
            mine = best == geom
            colour = [jnp.where(mine, rgb_table[geom, c], colour[c]) for c in range(3)]
        if self.config.checker_floor:
            r_cam, origin = frames["r_cam"], frames["origin"]
            for k in np.flatnonzero(sc.checker):
                u = origin[k, 0] + depth * (x * r_cam[k, 0, 0] + y * r_cam[k, 1, 0] - r_cam[k, 2, 0])
                v = origin[k, 1] + depth * (x * r_cam[k, 0, 1] + y * r_cam[k, 1, 1] - r_cam[k, 2, 1])
                squares = [c * sc.checker_scale[k, i] for i, c in enumerate((u, v))]
                squares = [c + sc.checker_offset[k, i] if sc.checker_offset[k, i] else c for i, c in enumerate(squares)]
                odd = ((_floor_int(squares[0]) + _floor_int(squares[1])) & 1) == 1
                mine = best == k
                if geom_rgb.size == 0:
                    tints = [sc.checker_rgb[k, :, c] for c in range(3)]
                else:  # MuJoCo multiplies the texture by the (changed) colour
                    tints = [sc.checker_texture[k, :, c] * rgb_table[k, c] for c in range(3)]
                colour = [jnp.where(mine, jnp.where(odd, tints[c][1], tints[c][0]), colour[c]) for c in range(3)]
        return tuple(colour)

    def incident_light(self, poses: Poses, padded: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, ...]:
        """The light falling on each pixel's surface, float32 ``1 x (H, W)`` when all lights
        are grey (dm_control's are) else ``3 x (H, W)``.

        The normal for Lambert shading comes from the hit points of neighbouring pixels on
        the same geom (the one-sided difference with the smaller depth step, so edges do not
        bend it), which needs no per-geom work per pixel.
        """
        sc = self.scene
        depth_p, best_p = padded
        depth = depth_p[1:-1, 1:-1]
        x, y = jnp.asarray(self.x), jnp.asarray(self.y)
        tangent_x = _surface_tangent(depth_p, best_p, x, y, self.pixel_pitch[0], axis=1)
        tangent_y = _surface_tangent(depth_p, best_p, x, y, -self.pixel_pitch[1], axis=0)
        normal = _cross(tangent_x, tangent_y)
        # < 0 when facing the camera (the hit point is depth * (x, y, -1))
        facing = normal[0] * x + normal[1] * y - normal[2]
        normal = [jnp.where(facing > 0, -n, n) for n in normal]
        inv_len = jax.lax.rsqrt(jnp.maximum(sum(n * n for n in normal), 1e-30))
        position, direction = self.lights_in_camera_frame(poses)
        # headlight: directional, along the view direction
        cosines = [jnp.maximum(normal[2], 0.0) * inv_len]
        point = (depth * x, depth * y, -depth)
        for j in range(len(sc.light_mode)):
            if sc.light_directional[j]:
                toward = [-direction[j, i] for i in range(3)]
                cosines.append(jnp.maximum(sum(normal[i] * toward[i] for i in range(3)), 0.0) * inv_len)
                continue
            toward = [position[j, i] - point[i] for i in range(3)]
            inv_dist = jax.lax.rsqrt(jnp.maximum(sum(t * t for t in toward), 1e-30))
            toward = [t * inv_dist for t in toward]
            lit = jnp.maximum(sum(normal[i] * toward[i] for i in range(3)), 0.0) * inv_len
            spot = -sum(toward[i] * direction[j, i] for i in range(3))
            exponent = float(sc.light_exponent[j])
            falloff = (
                jax.lax.integer_pow(jnp.maximum(spot, 0.0), int(exponent))
                if exponent.is_integer()
                else jnp.maximum(spot, 0.0) ** exponent
            )
            cone = jnp.where(spot >= sc.light_cos_cutoff[j], falloff, 0.0)
            cosines.append(lit * cone)
        diffuse = np.concatenate([sc.headlight_diffuse[None], sc.light_diffuse], axis=0)
        grey = np.allclose(diffuse, diffuse[:, :1]) and np.allclose(sc.ambient, sc.ambient[0])
        channels = (0,) if grey else (0, 1, 2)
        light = [sc.ambient[c] + sum(diffuse[j, c] * cosines[j] for j in range(len(cosines))) for c in channels]
        return tuple(light)

    def lights_in_camera_frame(self, poses: Poses) -> tuple[jax.Array, jax.Array]:
        """Model lights in camera coordinates: positions ``(L, 3)`` and unit directions they
        shine along ``(L, 3)``, as MuJoCo's ``mj_camlight`` places them."""
        sc = self.scene
        if sc.light_mode.shape[0] == 0:
            return jnp.zeros((0, 3)), jnp.zeros((0, 3))
        mats = poses["light_body_mat"]
        offset = jnp.asarray(sc.light_offset)
        mode = sc.light_mode
        aimed = mode >= scene_lib.LIGHT_TARGETBODY
        fixed = jnp.asarray((mode == scene_lib.LIGHT_FIXED) | aimed)[:, None]  # placed in the body frame
        follows_com = mode == scene_lib.LIGHT_TRACKCOM
        world_pos = jnp.where(
            fixed,
            poses["light_body_pos"] + jnp.einsum("lij,lj->li", mats, offset),
            jnp.where(jnp.asarray(follows_com)[:, None], poses["light_body_com"], poses["light_body_pos"]) + offset,
        )
        world_dir = jnp.where(
            fixed, jnp.einsum("lij,lj->li", mats, jnp.asarray(sc.light_dirs)), jnp.asarray(sc.light_dirs)
        )
        if sc.has_aimed_lights:  # at the target body or its subtree's centre of mass
            at_com = jnp.asarray(mode == scene_lib.LIGHT_TARGETBODYCOM)[:, None]
            target = jnp.where(at_com, poses["light_target_com"], poses["light_target_pos"])
            world_dir = jnp.where(jnp.asarray(aimed)[:, None], target - world_pos, world_dir)
        world_dir = world_dir / jnp.linalg.norm(world_dir, axis=-1, keepdims=True)
        cam_mat = poses["cam_mat"]
        return (world_pos - poses["cam_pos"]) @ cam_mat, world_dir @ cam_mat

    def sky_gradient(self, cam_mat: jax.Array) -> list[jax.Array]:
        """``[3 x (H, W)]`` float32 background: the skybox gradient over world elevation of the
        rays of a camera of orientation ``cam_mat`` ``(3, 3)``, or a flat colour
        (``sky="color"``)."""
        sc, cfg = self.scene, self.config
        h, w = cfg.height, cfg.width
        if cfg.sky == "color":
            return [jnp.full((h, w), c, jnp.float32) for c in cfg.background_color]
        x = jnp.asarray(self.x)
        y = jnp.asarray(self.y)
        inv_len = jax.lax.rsqrt(x * x + y * y + 1.0)
        z = (x * cam_mat[2, 0] + y * cam_mat[2, 1] - cam_mat[2, 2]) * inv_len
        return [jnp.clip(sc.sky_mid[c] + sc.sky_slope[c] * z, 0.0, 1.0) for c in range(3)]


def _floor_int(a: jax.Array) -> jax.Array:
    """``floor(a)`` as int32 of ``a``'s shape (a truncating conversion and a fix-up:
    vectorises on CPU, where ``jnp.floor`` may not)."""
    truncated = a.astype(jnp.int32)
    return truncated - (a < truncated.astype(a.dtype)).astype(jnp.int32)


def _surface_tangent(
    depth_p: jax.Array, best_p: jax.Array, x: jax.Array, y: jax.Array, pixel: float, axis: int
) -> list[jax.Array]:
    """Tangent ``[3 x (H, W)]`` along ``axis`` (columns: 1, rows: 0) between the hit points
    ``depth * (x, y, -1)`` of neighbouring pixels on the same geom: the forward or backward
    difference with the smaller depth step; where neither neighbour is on the same geom, a
    step of one pixel along the image axis at the pixel's depth. ``depth_p``, ``best_p`` are
    padded by one pixel, ``(H + 2, W + 2)`` float32; ``x`` ``(1, W)`` and ``y`` ``(H, 1)``
    are the pixels' image coordinates; ``pixel`` is the pixel pitch in image coordinates
    (positive along columns, negative along rows)."""

    def window(a: jax.Array, offset: int) -> jax.Array:
        rows = slice(1 + offset, a.shape[0] - 1 + offset) if axis == 0 else slice(1, -1)
        cols = slice(1 + offset, a.shape[1] - 1 + offset) if axis == 1 else slice(1, -1)
        return a[rows, cols]

    depth, best = window(depth_p, 0), window(best_p, 0)
    depth_ahead, depth_behind = window(depth_p, 1), window(depth_p, -1)
    same_ahead = window(best_p, 1) == best
    same_behind = window(best_p, -1) == best
    step_ahead = depth_ahead - depth
    step_behind = depth - depth_behind
    use_ahead = same_ahead & (~same_behind | (jnp.abs(step_ahead) <= jnp.abs(step_behind)))
    use_behind = same_behind & ~use_ahead
    step = jnp.where(use_ahead, step_ahead, jnp.where(use_behind, step_behind, 0.0))
    # difference of depth * u between the pair: step * u + (the later pixel's depth) * pitch
    far = jnp.where(use_ahead, depth_ahead, jnp.where(use_behind, depth_behind, depth))
    if axis == 1:
        return [step * x + far * pixel, step * y, -step]
    return [step * x, step * y + far * pixel, -step]


def _cross(u: Sequence[jax.Array], v: Sequence[jax.Array]) -> list[jax.Array]:
    """Cross product of two 3-vectors given as lists of 3 arrays (of shapes that broadcast),
    as such a list."""
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
