"""The ray-cast RGB-D camera: one ``mjx.Data`` -> an RGB image and a depth map.

Every pixel's ray is tested against every rendered geom in closed form, with all geometry
moved into the camera frame first: a pixel's ray is ``t * (x, y, -1)`` in camera coordinates,
so the ray parameter ``t`` *is* the depth along the optical axis, and each geom's local ray
direction is an affine function of the pixel's ``(x, y)``. The per-geom loop is unrolled in
Python (geom types and sizes are static), so XLA fuses the whole image into one elementwise
loop with a running nearest-hit selection and no ``(pixels x geoms)`` intermediate.
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from iap_mjx.render import intersect
from iap_mjx.render import scene as scene_lib

SHADINGS = ("lambert", "flat")
SKIES = ("skybox", "color")


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """Static settings of a camera (hashable).

    Attributes:
      camera_id: index into the model's cameras (``-1`` is not supported: use a model camera).
      height, width: image size in pixels.
      geom_groups: geom groups drawn (MuJoCo's renderer shows 0, 1, 2 by default).
      shading: ``"lambert"`` (ambient + headlight + the model's lights as directional lights)
        or ``"flat"`` (the geom colour as is).
      sky: where no geom is hit: ``"skybox"`` (a vertical gradient fitted to the model's skybox
        texture) or ``"color"`` (``background_color``). A per-call ``background`` image given
        to ``render`` replaces either.
      background_color: RGB in [0, 1] for ``sky="color"``.
      checker_floor: draw textured planes as dm_control's 2x2 checker (else flat material colour).
    """

    camera_id: int = 0
    height: int = 100
    width: int = 100
    geom_groups: tuple[int, ...] = (0, 1, 2)
    shading: str = "lambert"
    sky: str = "skybox"
    background_color: tuple[float, float, float] = (0.0, 0.0, 0.0)
    checker_floor: bool = True

    def __post_init__(self):
        if not isinstance(self.camera_id, int) or self.camera_id < 0:
            raise ValueError(f"camera_id must be an int >= 0 (a model camera), got {self.camera_id!r}")
        for name in ("height", "width"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        if not all(isinstance(g, int) and 0 <= g < 6 for g in self.geom_groups):
            raise ValueError(f"geom_groups must be ints in 0..5, got {self.geom_groups!r}")
        if self.shading not in SHADINGS:
            raise ValueError(f"shading must be one of {SHADINGS}, got {self.shading!r}")
        if self.sky not in SKIES:
            raise ValueError(f"sky must be one of {SKIES}, got {self.sky!r}")
        if len(self.background_color) != 3:
            raise ValueError(f"background_color must be 3 floats, got {self.background_color!r}")
        object.__setattr__(self, "geom_groups", tuple(self.geom_groups))
        object.__setattr__(self, "background_color", tuple(float(c) for c in self.background_color))


class Camera:
    """A ray-cast RGB-D camera for one model camera.

    ``Camera(mj_model, camera_id=0, height=100, width=100, **config)`` reads the static scene
    (geom types, sizes, colours, lights) once; ``render(data)`` is pure and works under
    ``jit`` and ``vmap``. A camera is hashable (by its config and scene content), so it can be
    a static argument or live inside a hashable env.

    Conventions (kept by every method):
      - pixel ``(row, col)`` looks through the pixel centre; row 0 is the top of the image,
        column 0 the left; the vertical field of view is ``cam_fovy``, the horizontal one
        follows from the aspect ratio (as MuJoCo's renderer);
      - the pose is ``data.cam_xpos``/``data.cam_xmat`` (so tracking cameras follow after
        ``mjx.forward``/``mjx.step``); the camera looks along its local -z, +y up;
      - depth is the distance along the optical axis (MuJoCo's linearised depth buffer), in
        metres;
      - a pixel whose ray hits nothing closer than the far plane (``vis.map.zfar * extent``, as
        MuJoCo's renderer clips) gets the background colour and depth equal to the far plane
        ``self.zfar`` (finite, so depth is safe to feed to a network).
    """

    def __init__(self, mj_model: mujoco.MjModel, camera_id: int = 0, height: int = 100,
                 width: int = 100, **config):
        self.config = CameraConfig(camera_id=camera_id, height=height, width=width, **config)
        if camera_id >= mj_model.ncam:
            raise ValueError(f"camera_id must be < the model's ncam={mj_model.ncam}, got {camera_id}")
        self.scene = scene_lib.build_scene(mj_model, self.config.geom_groups)
        self.fovy = float(mj_model.cam_fovy[camera_id])
        self.zfar = float(self.scene.zfar)
        half_h = np.tan(np.deg2rad(self.fovy) / 2.0)
        half_w = half_h * width / height
        cols = (np.arange(width) + 0.5) / width * 2.0 - 1.0
        rows = 1.0 - (np.arange(height) + 0.5) / height * 2.0
        self._x = (cols * half_w).astype(np.float32)[None, :]
        self._y = (rows * half_h).astype(np.float32)[:, None]
        self._key = (self.config, self.scene.digest(), self.fovy)

    def __hash__(self) -> int:
        return hash(self._key)

    def __eq__(self, other) -> bool:
        return isinstance(other, Camera) and self._key == other._key

    def __repr__(self) -> str:
        c = self.config
        return (f"Camera(camera_id={c.camera_id}, height={c.height}, width={c.width}, "
                f"geoms={len(self.scene.geom_ids)}, shading={c.shading!r})")

    @property
    def geom_ids(self) -> np.ndarray:
        """``(G,)`` the MuJoCo ids of the geoms this camera draws."""
        return self.scene.geom_ids

    def ray_directions(self) -> np.ndarray:
        """``(H, W, 3)`` float32 pixel ray directions ``(x, y, -1)`` in the camera frame
        (not normalised: ``depth * direction`` is the hit point)."""
        h, w = self.config.height, self.config.width
        x = np.broadcast_to(self._x, (h, w))
        y = np.broadcast_to(self._y, (h, w))
        return np.stack([x, y, -np.ones((h, w), np.float32)], axis=-1)

    def render(self, data: mjx.Data, background: Optional[jax.Array] = None,
               geom_rgb: Optional[jax.Array] = None) -> tuple[jax.Array, jax.Array]:
        """Renders one state.

        Args:
          data: an ``mjx.Data`` after kinematics (``geom_xpos``, ``geom_xmat``, ``cam_xpos``,
            ``cam_xmat``; ``xmat`` for lights fixed to bodies).
          background: optional ``(H, W, 3)`` image in [0, 1] shown where nothing is hit
            (e.g. a Distracting Control Suite frame); replaces the sky.
          geom_rgb: optional ``(G, 3)`` colours replacing the model's (colour perturbations),
            one row per ``self.geom_ids`` entry.

        Returns:
          rgb ``(H, W, 3)`` float32 in [0, 1] and depth ``(H, W)`` float32 in metres.
        """
        depth, _, rgb = self._cast(data, colour=True, background=background, geom_rgb=geom_rgb)
        return rgb, depth

    def trace(self, data: mjx.Data) -> tuple[jax.Array, jax.Array]:
        """Geometry only: depth ``(H, W)`` float32 (far plane where nothing is hit) and the
        hit geom's MuJoCo id ``(H, W)`` int32 (``-1`` where nothing is hit)."""
        depth, index, _ = self._cast(data, colour=False)
        ids = jnp.asarray(np.append(self.scene.geom_ids, -1).astype(np.int32))
        return depth, ids[index]

    def _cast(self, data, colour: bool, background=None, geom_rgb=None):
        sc, cfg = self.scene, self.config
        h, w = cfg.height, cfg.width
        n_geom = len(sc.geom_ids)
        cam_pos = data.cam_xpos[cfg.camera_id]
        cam_mat = data.cam_xmat[cfg.camera_id]
        gids = jnp.asarray(sc.geom_ids)
        geom_pos = data.geom_xpos[gids]
        geom_mat = data.geom_xmat[gids]
        # r_cam[k] = cam_mat^T geom_mat[k]: geom axes in camera coordinates; its rows are the
        # camera axes in geom coordinates, so a camera-frame ray (x, y, -1) has local
        # direction x * r_cam[k, 0] + y * r_cam[k, 1] - r_cam[k, 2].
        r_cam = jnp.einsum("ji,kjl->kil", cam_mat, geom_mat)
        origin = jnp.einsum("kji,kj->ki", geom_mat, cam_pos[None] - geom_pos)
        x = jnp.asarray(self._x)
        y = jnp.asarray(self._y)

        best_t = jnp.full((h, w), sc.zfar, jnp.float32)
        best_k = jnp.full((h, w), n_geom, jnp.int32)
        if colour:
            toward_lights = self._light_vectors(data, geom_mat, r_cam)
            base_rgb = jnp.asarray(sc.geom_rgb) if geom_rgb is None else jnp.asarray(geom_rgb, jnp.float32)
            best_rgb = [jnp.zeros((h, w), jnp.float32) for _ in range(3)]
            best_cos = [jnp.zeros((h, w), jnp.float32) for _ in range(toward_lights.shape[1])]
        for k in range(n_geom):
            gtype = int(sc.geom_type[k])
            size = tuple(float(s) for s in sc.geom_size[k])
            o = (origin[k, 0], origin[k, 1], origin[k, 2])
            d = tuple(x * r_cam[k, 0, i] + (y * r_cam[k, 1, i] - r_cam[k, 2, i]) for i in range(3))
            t, n = intersect.BY_TYPE[gtype](o, d, size)
            closer = t < best_t
            best_t = jnp.where(closer, t, best_t)
            best_k = jnp.where(closer, k, best_k)
            if not colour:
                continue
            if cfg.checker_floor and bool(sc.checker[k]) and geom_rgb is None:
                u = (o[0] + t * d[0]) * (2.0 * sc.checker_scale[k, 0])
                v = (o[1] + t * d[1]) * (2.0 * sc.checker_scale[k, 1])
                odd = jnp.mod(jnp.floor(u) + jnp.floor(v), 2.0) > 0.5
                rgb_k = [jnp.where(odd, sc.checker_rgb[k, 1, i], sc.checker_rgb[k, 0, i]) for i in range(3)]
            else:
                rgb_k = [base_rgb[k, i] for i in range(3)]
            for i in range(3):
                best_rgb[i] = jnp.where(closer, rgb_k[i], best_rgb[i])
            if cfg.shading == "lambert":
                inv_norm = jax.lax.rsqrt(jnp.maximum(n[0] * n[0] + n[1] * n[1] + n[2] * n[2], 1e-30))
                for j in range(len(best_cos)):
                    lj = toward_lights[k, j]
                    cos = jnp.maximum(n[0] * lj[0] + n[1] * lj[1] + n[2] * lj[2], 0.0) * inv_norm
                    best_cos[j] = jnp.where(closer, cos, best_cos[j])

        depth = best_t
        if not colour:
            return depth, best_k, None
        if cfg.shading == "lambert":
            diffuse = np.concatenate([sc.headlight_diffuse[None], sc.light_diffuse], axis=0)
            light = [sc.ambient[i] + sum(diffuse[j, i] * best_cos[j] for j in range(len(best_cos)))
                     for i in range(3)]
            surface = jnp.stack([best_rgb[i] * light[i] for i in range(3)], axis=-1)
        else:
            surface = jnp.stack(best_rgb, axis=-1)
        surface = jnp.clip(surface, 0.0, 1.0)
        if background is None:
            background = self._sky(cam_mat)
        hit = (best_k < n_geom)[..., None]
        rgb = jnp.where(hit, surface, jnp.asarray(background, jnp.float32))
        return depth, best_k, rgb

    def _light_vectors(self, data, geom_mat, r_cam) -> jax.Array:
        """``(G, 1 + L, 3)`` unit vectors toward the headlight and each model light, in each
        geom's local frame (the headlight shines along the camera's view direction)."""
        sc = self.scene
        head = r_cam[:, 2, :][:, None, :]
        if sc.light_dirs.shape[0] == 0:
            return head
        body_mat = data.xmat[jnp.asarray(sc.light_bodyid)]
        world_dirs = jnp.einsum("lij,lj->li", body_mat, jnp.asarray(sc.light_dirs))
        world_dirs = world_dirs / jnp.linalg.norm(world_dirs, axis=-1, keepdims=True)
        local = jnp.einsum("kji,lj->kli", geom_mat, -world_dirs)
        return jnp.concatenate([head, local], axis=1)

    def _sky(self, cam_mat) -> jax.Array:
        """``(H, W, 3)`` background: the skybox gradient over world elevation, or a flat colour."""
        sc, cfg = self.scene, self.config
        h, w = cfg.height, cfg.width
        if cfg.sky == "color":
            return jnp.broadcast_to(jnp.asarray(cfg.background_color, jnp.float32), (h, w, 3))
        x = jnp.asarray(self._x)
        y = jnp.asarray(self._y)
        inv_len = jax.lax.rsqrt(x * x + y * y + 1.0)
        z = (x * cam_mat[2, 0] + y * cam_mat[2, 1] - cam_mat[2, 2]) * inv_len
        sky = jnp.asarray(sc.sky_mid) + jnp.asarray(sc.sky_slope) * z[..., None]
        return jnp.clip(sky, 0.0, 1.0)
