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
      batch_chunk: under ``vmap``, images rendered together per step of the loop over the batch
        (small enough for the intermediates to stay in cache).
    """

    camera_id: int = 0
    height: int = 100
    width: int = 100
    geom_groups: tuple[int, ...] = (0, 1, 2)
    shading: str = "lambert"
    sky: str = "skybox"
    background_color: tuple[float, float, float] = (0.0, 0.0, 0.0)
    checker_floor: bool = True
    batch_chunk: int = 4

    def __post_init__(self):
        if not isinstance(self.camera_id, int) or self.camera_id < 0:
            raise ValueError(f"camera_id must be an int >= 0 (a model camera), got {self.camera_id!r}")
        for name in ("height", "width"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        if not all(isinstance(g, int) and 0 <= g < 6 for g in self.geom_groups):
            raise ValueError(f"geom_groups must be ints in 0..5, got {self.geom_groups!r}")
        if not isinstance(self.batch_chunk, int) or self.batch_chunk < 1:
            raise ValueError(f"batch_chunk must be a positive int, got {self.batch_chunk!r}")
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
        self._kernels = {}

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
        """Renders one state (``vmap`` it for a batch).

        Args:
          data: an ``mjx.Data`` after kinematics (``geom_xpos``, ``geom_xmat``, ``cam_xpos``,
            ``cam_xmat``; ``xmat`` for lights fixed to bodies).
          background: optional ``(H, W, 3)`` image in [0, 1] shown where nothing is hit
            (e.g. a Distracting Control Suite frame); replaces the sky.
          geom_rgb: optional ``(G, 3)`` colours replacing the model's (colour perturbations),
            one row per ``self.geom_ids`` entry; textured floors then draw flat.

        Returns:
          rgb ``(H, W, 3)`` float32 in [0, 1] and depth ``(H, W)`` float32 in metres.
        """
        cfg = self.config
        if background is None:
            background = jnp.zeros((0,), jnp.float32)
        elif tuple(background.shape) != (cfg.height, cfg.width, 3):
            raise ValueError(f"background must have shape {(cfg.height, cfg.width, 3)}, got {background.shape}")
        if geom_rgb is None:
            geom_rgb = jnp.zeros((0,), jnp.float32)
        elif tuple(geom_rgb.shape) != (len(self.scene.geom_ids), 3):
            raise ValueError(f"geom_rgb must have shape {(len(self.scene.geom_ids), 3)}, got {geom_rgb.shape}")
        rgb, depth, _ = self._batchable(True)(self._poses(data), background, geom_rgb)
        return rgb, depth

    def trace(self, data: mjx.Data) -> tuple[jax.Array, jax.Array]:
        """Geometry only: depth ``(H, W)`` float32 (far plane where nothing is hit) and the
        hit geom's MuJoCo id ``(H, W)`` int32 (``-1`` where nothing is hit)."""
        empty = jnp.zeros((0,), jnp.float32)
        _, depth, ids = self._batchable(False)(self._poses(data), empty, empty)
        return depth, ids

    # -- implementation ---------------------------------------------------------------------

    def _poses(self, data: mjx.Data) -> dict[str, jax.Array]:
        """The few per-state arrays the renderer reads."""
        sc = self.scene
        cam = self.config.camera_id
        gids = jnp.asarray(sc.geom_ids)
        return {
            "cam_pos": data.cam_xpos[cam],
            "cam_mat": data.cam_xmat[cam],
            "geom_pos": data.geom_xpos[gids],
            "geom_mat": data.geom_xmat[gids],
            "light_body_mat": data.xmat[jnp.asarray(sc.light_bodyid)],
        }

    def _batchable(self, colour: bool):
        """The single-image kernel wrapped so that ``vmap`` over a batch runs it as a loop over
        chunks of ``config.batch_chunk`` images (a ``vmap`` inside a ``lax.map``): each chunk's
        intermediates stay in cache, which on CPU is several times faster than one
        batch-wide pass per operation."""
        cached = self._kernels.get(colour)
        if cached is not None:
            return cached

        def kernel(poses, background, geom_rgb):
            return self._kernel(poses, background, geom_rgb, colour)

        batched = jax.custom_batching.custom_vmap(kernel)

        @batched.def_vmap
        def _rule(axis_size, in_batched, poses, background, geom_rgb):
            args = jax.tree.map(
                lambda x, b: x if b else jnp.broadcast_to(x, (axis_size,) + x.shape),
                (poses, background, geom_rgb), tuple(in_batched))
            out = jax.lax.map(lambda a: kernel(*a), args, batch_size=min(self.config.batch_chunk, axis_size))
            return out, jax.tree.map(lambda _: True, out)

        self._kernels[colour] = batched
        return batched

    def _kernel(self, poses, background, geom_rgb, colour: bool):
        """One image: ``(rgb (H, W, 3) or None, depth (H, W), geom id (H, W))``."""
        sc, cfg = self.scene, self.config
        n_geom = len(sc.geom_ids)
        cam_mat = poses["cam_mat"]
        geom_mat = poses["geom_mat"]
        # r_cam[k] = cam_mat^T geom_mat[k]: geom axes in camera coordinates. Its rows are the
        # camera axes in geom coordinates, so the camera-frame ray (x, y, -1) has the local
        # direction x * r_cam[k, 0] + y * r_cam[k, 1] - r_cam[k, 2].
        r_cam = jnp.einsum("ji,kjl->kil", cam_mat, geom_mat)
        origin = jnp.einsum("kji,kj->ki", geom_mat, poses["cam_pos"][None] - poses["geom_pos"])
        x = jnp.asarray(self._x)
        y = jnp.asarray(self._y)

        depth, best = self._nearest_hits(r_cam, origin, x, y)
        ids = jnp.asarray(np.append(sc.geom_ids, -1).astype(np.int32))[best]
        if not colour:
            return None, depth, ids
        lights = self._light_vectors(poses, r_cam)
        rgb_table = jnp.asarray(sc.geom_rgb) if geom_rgb.size == 0 else geom_rgb.astype(jnp.float32)
        surface = self._shade(r_cam, origin, lights, rgb_table, depth, best, x, y,
                              checker=geom_rgb.size == 0 and cfg.checker_floor)
        if background.size == 0:
            background = self._sky(cam_mat)
        rgb = jnp.where((best < n_geom)[..., None], surface, background.astype(jnp.float32))
        return rgb, depth, ids

    def _nearest_hits(self, r_cam, origin, x, y):
        """Depth ``(H, W)`` of the nearest hit (far plane if none) and the index ``(H, W)``
        into the rendered geoms (``G`` if none): every geom's closed form, then one variadic
        min-reduction over the geoms."""
        sc = self.scene
        n_geom = len(sc.geom_ids)
        hits = []
        for k in range(n_geom):
            size = tuple(float(s) for s in sc.geom_size[k])
            o = (origin[k, 0], origin[k, 1], origin[k, 2])
            d = tuple(x * r_cam[k, 0, i] + (y * r_cam[k, 1, i] - r_cam[k, 2, i]) for i in range(3))
            t, _ = intersect.BY_TYPE[int(sc.geom_type[k])](o, d, size)
            hits.append(t)
        hits.append(jnp.full(jnp.broadcast_shapes(x.shape, y.shape), sc.zfar, jnp.float32))
        stacked = jnp.stack(hits, axis=0)
        index = jax.lax.broadcasted_iota(jnp.int32, stacked.shape, 0)

        def nearer(a, b):
            take_b = (b[0] < a[0]) | ((b[0] == a[0]) & (b[1] < a[1]))
            return jnp.where(take_b, b[0], a[0]), jnp.where(take_b, b[1], a[1])

        depth, best = jax.lax.reduce(
            (stacked, index), (jnp.float32(jnp.inf), jnp.int32(n_geom)), nearer, (0,))
        return depth, best

    def _shade(self, r_cam, origin, lights, rgb_table, depth, best, x, y, checker: bool):
        """``(H, W, 3)`` surface colour of each pixel's nearest geom: the per-geom constants are
        picked by a one-hot matmul, then the hit point, normal, Lambert terms and the checker
        floor are computed once per pixel."""
        sc, cfg = self.scene, self.config
        n_geom = len(sc.geom_ids)
        h, w = cfg.height, cfg.width
        types = sorted(set(int(t) for t in sc.geom_type))
        size = sc.geom_size.astype(np.float64)
        safe = np.where(size > 0, size, 1.0)
        static_cols = np.concatenate([
            1.0 / safe, 1.0 / safe ** 2,
            np.stack([sc.geom_type == t for t in types], axis=1),
            sc.checker[:, None] & checker, 2.0 * sc.checker_scale, sc.checker_rgb.reshape(n_geom, 6),
        ], axis=1).astype(np.float32)
        n_lights = lights.shape[1]
        table = jnp.concatenate([
            r_cam[:, 0, :], r_cam[:, 1, :], -r_cam[:, 2, :], origin,
            lights.reshape(n_geom, 3 * n_lights), rgb_table, jnp.asarray(static_cols),
        ], axis=1)
        table = jnp.concatenate([table, jnp.zeros((1, table.shape[1]), table.dtype)], axis=0)
        onehot = (best.reshape(-1, 1) == jnp.arange(n_geom + 1)[None, :]).astype(jnp.float32)
        per_pixel = jnp.dot(onehot, table, precision=jax.lax.Precision.HIGHEST).reshape(h, w, -1)
        cols = iter(range(per_pixel.shape[-1]))

        def take(n):
            return [per_pixel[..., next(cols)] for _ in range(n)]

        a, b, e, o = take(3), take(3), take(3), take(3)
        light_vecs = [take(3) for _ in range(n_lights)]
        base = take(3)
        inv_s, inv_s2 = take(3), take(3)
        is_type = dict(zip(types, take(len(types))))
        is_checker, scale, checker_rgb = take(1)[0], take(2), take(6)

        p = [o[i] + depth * (x * a[i] + y * b[i] + e[i]) for i in range(3)]
        normal = [jnp.zeros((h, w), jnp.float32) for _ in range(3)]
        for gtype, weight in is_type.items():
            n_t = _local_normal(gtype, p, inv_s, inv_s2)
            normal = [normal[i] + weight * n_t[i] for i in range(3)]
        colour = base
        if checker and bool(sc.checker.any()):
            u = jnp.floor(p[0] * scale[0]) + jnp.floor(p[1] * scale[1])
            odd = u - 2.0 * jnp.floor(0.5 * u)
            tex = [checker_rgb[i] + odd * (checker_rgb[3 + i] - checker_rgb[i]) for i in range(3)]
            colour = [base[i] + is_checker * (tex[i] - base[i]) for i in range(3)]
        if cfg.shading == "flat":
            return jnp.clip(jnp.stack(colour, axis=-1), 0.0, 1.0)
        inv_len = jax.lax.rsqrt(jnp.maximum(sum(n * n for n in normal), 1e-30))
        diffuse = np.concatenate([sc.headlight_diffuse[None], sc.light_diffuse], axis=0)
        cosines = [jnp.maximum(sum(normal[i] * lv[i] for i in range(3)), 0.0) * inv_len for lv in light_vecs]
        light = [sc.ambient[c] + sum(diffuse[j, c] * cosines[j] for j in range(n_lights)) for c in range(3)]
        return jnp.clip(jnp.stack([colour[c] * light[c] for c in range(3)], axis=-1), 0.0, 1.0)

    def _light_vectors(self, poses, r_cam) -> jax.Array:
        """``(G, 1 + L, 3)`` unit vectors toward the headlight and each model light, in each
        geom's local frame (the headlight shines along the camera's view direction)."""
        sc = self.scene
        head = r_cam[:, 2, :][:, None, :]
        if sc.light_dirs.shape[0] == 0:
            return head
        world_dirs = jnp.einsum("lij,lj->li", poses["light_body_mat"], jnp.asarray(sc.light_dirs))
        world_dirs = world_dirs / jnp.linalg.norm(world_dirs, axis=-1, keepdims=True)
        local = jnp.einsum("kji,lj->kli", poses["geom_mat"], -world_dirs)
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


def _local_normal(gtype: int, p, inv_s, inv_s2):
    """Outward normal (not normalised) of a geom of type ``gtype`` at local hit point ``p``;
    sizes come per pixel as ``inv_s = 1 / size`` (so one formula serves all geoms of a type)."""
    zero = jnp.zeros_like(p[0])
    if gtype == scene_lib.PLANE:
        return zero, zero, zero + 1.0
    if gtype == scene_lib.SPHERE:
        return tuple(p)
    if gtype == scene_lib.ELLIPSOID:
        return tuple(p[i] * inv_s2[i] for i in range(3))
    if gtype == scene_lib.CAPSULE:
        half = 1.0 / inv_s[1]
        return p[0], p[1], p[2] - jnp.clip(p[2], -half, half)
    if gtype == scene_lib.CYLINDER:
        radial = jnp.sqrt(p[0] * p[0] + p[1] * p[1]) * inv_s[0]
        cap = jnp.abs(p[2]) * inv_s[1] > radial
        return (jnp.where(cap, zero, p[0]), jnp.where(cap, zero, p[1]),
                jnp.where(cap, jnp.sign(p[2]), zero))
    if gtype == scene_lib.BOX:
        q = [jnp.abs(p[i]) * inv_s[i] for i in range(3)]
        return tuple(
            jnp.where((q[i] >= q[(i + 1) % 3]) & (q[i] >= q[(i + 2) % 3]), jnp.sign(p[i]), zero)
            for i in range(3))
    raise ValueError(f"unsupported geom type {gtype}")
