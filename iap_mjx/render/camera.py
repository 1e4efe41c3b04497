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
import functools
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
      tile: side in pixels of the square screen tiles used for culling.
      max_geoms_per_tile: slots per tile for each culled type group (types with more geoms than
        this, planes excepted, are culled per tile by projected bounds). A batch chunk in which
        some tile has more candidates is traced densely instead, so results never depend on it;
        0 turns culling off.
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
    tile: int = 10
    max_geoms_per_tile: int = 4

    def __post_init__(self):
        if not isinstance(self.camera_id, int) or self.camera_id < 0:
            raise ValueError(f"camera_id must be an int >= 0 (a model camera), got {self.camera_id!r}")
        for name in ("height", "width"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        if not all(isinstance(g, int) and 0 <= g < 6 for g in self.geom_groups):
            raise ValueError(f"geom_groups must be ints in 0..5, got {self.geom_groups!r}")
        for name in ("tile", "max_geoms_per_tile"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < (1 if name == "tile" else 0):
                raise ValueError(f"{name} must be an int >= {1 if name == 'tile' else 0}, got {value!r}")
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
        self._pixel_pitch = (float(2.0 * half_w / width), float(2.0 * half_h / height))
        self._y = (rows * half_h).astype(np.float32)[:, None]
        self._key = (self.config, self.scene.digest(), self.fovy)
        self._kernels = {}
        self._setup_tiles(half_w, half_h)
        k_max = self.config.max_geoms_per_tile
        groups = {}
        for k, gtype in enumerate(self.scene.geom_type):
            groups.setdefault(int(gtype), []).append(k)
        self._culled_groups = tuple(
            (gtype, tuple(members)) for gtype, members in sorted(groups.items())
            if gtype != scene_lib.PLANE and k_max > 0 and len(members) > k_max)
        culled = {k for _, members in self._culled_groups for k in members}
        self._dense_geoms = tuple(k for k in range(len(self.scene.geom_ids)) if k not in culled)

    def _setup_tiles(self, half_w: float, half_h: float) -> None:
        """Static tile layout: pixel image coordinates per tile and each tile's bounds."""
        cfg = self.config
        th, tw = min(cfg.tile, cfg.height), min(cfg.tile, cfg.width)
        ny, nx = -(-cfg.height // th), -(-cfg.width // tw)
        cols = ((np.arange(nx * tw) + 0.5) / cfg.width * 2.0 - 1.0) * half_w
        rows = (1.0 - (np.arange(ny * th) + 0.5) / cfg.height * 2.0) * half_h
        x = np.broadcast_to(cols[None, :], (ny * th, nx * tw)).reshape(ny, th, nx, tw)
        y = np.broadcast_to(rows[:, None], (ny * th, nx * tw)).reshape(ny, th, nx, tw)
        self._tile_grid = (ny, nx, th, tw)
        self._tile_x = np.moveaxis(x, 2, 1).reshape(ny * nx, th * tw).astype(np.float32)
        self._tile_y = np.moveaxis(y, 2, 1).reshape(ny * nx, th * tw).astype(np.float32)
        self._tile_bounds = np.stack([self._tile_x.min(1), self._tile_x.max(1),
                                      self._tile_y.min(1), self._tile_y.max(1)], axis=1)

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
        """The single-image program wrapped so that ``vmap`` over a batch runs it as a loop
        over chunks of ``config.batch_chunk`` images (a ``vmap`` inside a ``lax.map``): each
        chunk's intermediates stay in cache, which on CPU is several times faster than one
        batch-wide pass per operation; and the dense fallback of tile culling is a real branch
        taken only by chunks that need it."""
        cached = self._kernels.get(colour)
        if cached is not None:
            return cached

        def single(poses, background, geom_rgb):
            return self._program(poses, background, geom_rgb, colour, batched=False)

        batched = jax.custom_batching.custom_vmap(single)

        @batched.def_vmap
        def _rule(axis_size, in_batched, poses, background, geom_rgb):
            args = jax.tree.map(
                lambda x, b: x if b else jnp.broadcast_to(x, (axis_size,) + x.shape),
                (poses, background, geom_rgb), tuple(in_batched))
            chunk = min(self.config.batch_chunk, axis_size)
            n_chunks = -(-axis_size // chunk)
            padded = n_chunks * chunk

            def split(x):
                if padded != axis_size:
                    x = jnp.concatenate([x, jnp.repeat(x[-1:], padded - axis_size, axis=0)], axis=0)
                return x.reshape((n_chunks, chunk) + x.shape[1:])

            out = jax.lax.map(lambda a: self._program(*a, colour, batched=True),
                              jax.tree.map(split, args))
            out = jax.tree.map(lambda x: x.reshape((padded,) + x.shape[2:])[:axis_size], out)
            return out, jax.tree.map(lambda _: True, out)

        self._kernels[colour] = batched
        return batched

    def _program(self, poses, background, geom_rgb, colour: bool, batched: bool):
        """One image, or (``batched``) a leading axis of images: ``(rgb (H, W, 3) or None,
        depth (H, W), geom id (H, W))``. Culled tracing first; if any tile (of any image in
        the batch) has more candidate geoms than ``max_geoms_per_tile``, dense tracing.

        The trace ends in a ``lax.cond`` (on the camera pose being finite; a non-finite pose
        sees nothing): its results are materialised once, where XLA would otherwise fuse the
        nearest-hit selection into every shading consumer and redo it many times.
        """
        lift = jax.vmap if batched else (lambda f: f)
        frames = lift(self._frames)(poses)
        finite = jnp.all(jnp.isfinite(poses["cam_pos"])) & jnp.all(jnp.isfinite(poses["cam_mat"]))
        shape = jnp.shape(poses["cam_pos"])[:-1] + (self.config.height, self.config.width)

        def nothing():
            # derived from an input, so it carries the same sharding type under shard_map
            zero = 0.0 * jnp.nan_to_num(poses["cam_pos"][..., 0])[..., None, None]
            return (jnp.broadcast_to(zero + self.scene.zfar, shape),
                    jnp.broadcast_to(zero.astype(jnp.int32) + len(self.scene.geom_ids), shape))

        if self._culled_groups:
            depth, best, overflow = lift(self._trace_culled)(frames)
            depth, best = jax.lax.cond(
                jnp.any(overflow) | ~finite,
                lambda: jax.lax.cond(finite, lambda: lift(self._trace_dense)(frames), nothing),
                lambda: (depth, best))
        else:
            depth, best = jax.lax.cond(finite, lambda: lift(self._trace_dense)(frames), nothing)
        return lift(functools.partial(self._finish, colour=colour))(
            poses, frames, depth, best, background, geom_rgb)

    def _frames(self, poses) -> dict[str, jax.Array]:
        """Per-geom constants of one image in camera and local frames."""
        cam_mat = poses["cam_mat"]
        geom_mat = poses["geom_mat"]
        # r_cam[k] = cam_mat^T geom_mat[k]: geom axes in camera coordinates. Its rows are the
        # camera axes in geom coordinates, so the camera-frame ray (x, y, -1) has the local
        # direction x * r_cam[k, 0] + y * r_cam[k, 1] - r_cam[k, 2].
        r_cam = jnp.einsum("ji,kjl->kil", cam_mat, geom_mat)
        offset = poses["geom_pos"] - poses["cam_pos"][None]
        return {
            "r_cam": r_cam,
            "origin": -jnp.einsum("kji,kj->ki", geom_mat, offset),
            "centre": offset @ cam_mat,
        }

    def _trace_dense(self, frames):
        """Every geom against every pixel: depth and geom index ``(H, W)``."""
        x, y = jnp.asarray(self._x), jnp.asarray(self._y)
        r_cam, origin = frames["r_cam"], frames["origin"]
        candidates = [(self._intersect_static(k, r_cam, origin, x, y), k)
                      for k in range(len(self.scene.geom_ids))]
        return self._nearest(candidates, (self.config.height, self.config.width))

    def _trace_culled(self, frames):
        """Planes and small groups densely; each culled type group per tile through at most
        ``max_geoms_per_tile`` slots, picked by projected bounds: depth and geom index
        ``(H, W)``. Also returns ``overflow``,
        true if some tile had more overlapping geoms than slots (the result is then wrong and
        the caller falls back to ``_trace_dense``)."""
        sc = self.scene
        k_max = self.config.max_geoms_per_tile
        tx, ty = jnp.asarray(self._tile_x), jnp.asarray(self._tile_y)
        r_cam, origin = frames["r_cam"], frames["origin"]
        candidates = [(self._intersect_static(k, r_cam, origin, tx, ty), k)
                      for k in self._dense_geoms]
        overflow = jnp.zeros((), bool)
        for gtype, members in self._culled_groups:
            members_arr = jnp.asarray(members)
            overlap = self._tile_overlap(frames, members)
            overflow |= jnp.any(jnp.sum(overlap, axis=1) > k_max)
            priority = jnp.where(overlap, len(members) - jnp.arange(len(members)), 0)
            score, slot = jax.lax.top_k(priority, k_max)
            params = jnp.concatenate([
                r_cam[members_arr, 0, :], r_cam[members_arr, 1, :], -r_cam[members_arr, 2, :],
                origin[members_arr], jnp.asarray(sc.geom_size[list(members)]),
            ], axis=1)
            picked = params[slot]
            for s in range(k_max):
                col = [picked[:, s, i: i + 1] for i in range(15)]
                d = tuple(tx * col[i] + ty * col[3 + i] + col[6 + i] for i in range(3))
                t = intersect.BY_TYPE[gtype](tuple(col[9:12]), d, tuple(col[12:15]))
                t = jnp.where(score[:, s: s + 1] > 0, t, jnp.inf)
                candidates.append((t, members_arr[slot[:, s: s + 1]]))
        depth, best = self._nearest(candidates, tx.shape)
        return self._to_image(depth), self._to_image(best), overflow

    def _tile_overlap(self, frames, members):
        """``(tiles, len(members))`` bool: may the geom cover a pixel centre of the tile?
        Each geom is bounded by spheres (the two end spheres of a capsule or cylinder, one
        sphere otherwise), each sphere by a conservative box in image coordinates
        ``x / -z, y / -z``; a geom reaching the camera plane covers everything."""
        sc = self.scene
        idx = jnp.asarray(members)
        centre = frames["centre"][idx]
        axis = frames["r_cam"][idx, :, 2]
        radius, half = [], []
        for k in members:
            size = sc.geom_size[k]
            gtype = int(sc.geom_type[k])
            if gtype in (scene_lib.CAPSULE, scene_lib.CYLINDER):
                radius.append(size[0])
                half.append(size[1])
            elif gtype == scene_lib.BOX:
                radius.append(float(np.linalg.norm(size)))
                half.append(0.0)
            else:
                radius.append(float(np.max(size)) if gtype == scene_lib.ELLIPSOID else size[0])
                half.append(0.0)
        radius = jnp.asarray(np.asarray(radius, np.float32))[:, None]
        half = jnp.asarray(np.asarray(half, np.float32))[:, None, None]
        ends = centre[:, None, :] + jnp.asarray([1.0, -1.0])[None, :, None] * half * axis[:, None, :]
        near = -ends[..., 2] - radius
        far = -ends[..., 2] + radius
        crosses = jnp.any(near <= 1e-6, axis=1) & jnp.any(far > 0.0, axis=1)
        behind = jnp.all(far <= 0.0, axis=1)
        safe_near = jnp.maximum(near, 1e-6)

        def extent(c):
            lo = c - radius
            hi = c + radius
            lo = jnp.where(lo >= 0, lo / far, lo / safe_near)
            hi = jnp.where(hi >= 0, hi / safe_near, hi / far)
            return jnp.min(lo, axis=1) - 1e-4, jnp.max(hi, axis=1) + 1e-4

        x_lo, x_hi = extent(ends[..., 0])
        y_lo, y_hi = extent(ends[..., 1])
        t = self._tile_bounds
        overlap = ((x_lo[None] <= t[:, 1:2]) & (x_hi[None] >= t[:, 0:1])
                   & (y_lo[None] <= t[:, 3:4]) & (y_hi[None] >= t[:, 2:3]))
        return (overlap | crosses[None]) & ~behind[None]

    def _intersect_static(self, k, r_cam, origin, x, y):
        """Ray parameter (= depth) of geom ``k`` for pixels at image coordinates ``x, y``."""
        sc = self.scene
        size = tuple(float(s) for s in sc.geom_size[k])
        o = (origin[k, 0], origin[k, 1], origin[k, 2])
        d = tuple(x * r_cam[k, 0, i] + (y * r_cam[k, 1, i] - r_cam[k, 2, i]) for i in range(3))
        return intersect.BY_TYPE[int(sc.geom_type[k])](o, d, size)

    def _nearest(self, candidates, shape):
        """The nearest of ``(t, geom index)`` candidates and the far plane: depth (far plane if
        none) and geom index (``G`` if none).

        One running ``min`` over int32 keys: a positive float's bits order like its value, so
        the depth's low mantissa bits are replaced by the geom index and the smallest key is
        the nearest hit *and* says which geom it is (the depth loses those bits: a relative
        error below ``2**(bits - 23)``, under 1e-5 for up to 63 geoms).
        """
        n_geom = len(self.scene.geom_ids)
        mask = (1 << max(1, n_geom.bit_length())) - 1
        zfar_bits = int(np.float32(self.scene.zfar).view(np.int32))
        keys = [jnp.full(shape, (zfar_bits & ~mask) | n_geom, jnp.int32)]
        for t, k in candidates:
            bits = jax.lax.bitcast_convert_type(jnp.maximum(t, 0.0), jnp.int32)
            keys.append(jnp.broadcast_to((bits & ~mask) | k, shape))
        # A reduction (not a chain of minimums): XLA materialises its result once instead of
        # fusing the whole trace into each of its consumers.
        best = jnp.min(jnp.stack(keys), axis=0)
        index = best & mask
        depth = jax.lax.bitcast_convert_type(best & ~mask, jnp.float32)
        return jnp.where(index == n_geom, jnp.float32(self.scene.zfar), depth), index

    def _to_image(self, tiled):
        """``(tiles, tile pixels, ...)`` -> ``(H, W, ...)``."""
        cfg = self.config
        ny, nx, th, tw = self._tile_grid
        rest = tiled.shape[2:]
        image = tiled.reshape((ny, nx, th, tw) + rest)
        image = jnp.moveaxis(image, 2, 1).reshape((ny * th, nx * tw) + rest)
        return image[: cfg.height, : cfg.width]

    def _finish(self, poses, frames, depth, best, background, geom_rgb, colour: bool):
        """Depth and geom index ``(H, W)`` -> ``(rgb or None, depth, ids)`` images."""
        sc, cfg = self.scene, self.config
        ids = jnp.asarray(np.append(sc.geom_ids, -1).astype(np.int32))[best]
        if not colour:
            return None, depth, ids
        rgb_table = sc.geom_rgb if geom_rgb.size == 0 else geom_rgb.astype(jnp.float32)
        surface = self._shade(poses, frames, rgb_table, depth, best,
                              checker=geom_rgb.size == 0 and cfg.checker_floor)
        if background.size == 0:
            background = self._sky(poses["cam_mat"])
        else:
            background = [background[..., c].astype(jnp.float32) for c in range(3)]
        hit = best < len(sc.geom_ids)
        rgb = jnp.stack([jnp.where(hit, surface[c], background[c]) for c in range(3)], axis=-1)
        return rgb, depth, ids

    def _shade(self, poses, frames, rgb_table, depth, best, checker: bool):
        """``[3 x (H, W)]`` surface colour of each pixel's nearest geom.

        The colour is the geom's (or the checker floor's at the hit point); the normal for
        Lambert shading comes from the hit points of neighbouring pixels on the same geom
        (the one-sided difference with the smaller depth step, so edges do not bend it),
        which needs no per-geom work per pixel.
        """
        sc, cfg = self.scene, self.config
        n_geom = len(sc.geom_ids)
        x, y = jnp.asarray(self._x), jnp.asarray(self._y)
        colour = [jnp.zeros_like(depth) for _ in range(3)]
        for k in range(n_geom):
            mine = best == k
            colour = [jnp.where(mine, rgb_table[k, c], colour[c]) for c in range(3)]
        if checker:
            r_cam, origin = frames["r_cam"], frames["origin"]
            for k in np.flatnonzero(sc.checker):
                u = origin[k, 0] + depth * (x * r_cam[k, 0, 0] + y * r_cam[k, 1, 0] - r_cam[k, 2, 0])
                v = origin[k, 1] + depth * (x * r_cam[k, 0, 1] + y * r_cam[k, 1, 1] - r_cam[k, 2, 1])
                cell = (jnp.floor(u * sc.checker_scale[k, 0])
                        + jnp.floor(v * sc.checker_scale[k, 1]))
                odd = (cell - 2.0 * jnp.floor(0.5 * cell)) > 0.5
                mine = best == k
                colour = [jnp.where(mine, jnp.where(odd, sc.checker_rgb[k, 1, c], sc.checker_rgb[k, 0, c]),
                                    colour[c]) for c in range(3)]
        if cfg.shading == "flat":
            return [jnp.clip(c, 0.0, 1.0) for c in colour]
        tangent_x = _surface_step(depth, best, x, y, self._pixel_pitch[0], axis=1)
        tangent_y = _surface_step(depth, best, x, y, -self._pixel_pitch[1], axis=0)
        normal = _cross(tangent_x, tangent_y)
        # < 0 when facing the camera (the hit point is depth * (x, y, -1))
        facing = normal[0] * x + normal[1] * y - normal[2]
        normal = [jnp.where(facing > 0, -n, n) for n in normal]
        inv_len = jax.lax.rsqrt(jnp.maximum(sum(n * n for n in normal), 1e-30))
        toward = self._light_vectors(poses)
        diffuse = np.concatenate([sc.headlight_diffuse[None], sc.light_diffuse], axis=0)
        cosines = [jnp.maximum(sum(normal[i] * toward[j, i] for i in range(3)), 0.0) * inv_len
                   for j in range(toward.shape[0])]
        grey = np.allclose(diffuse, diffuse[:, :1]) and np.allclose(sc.ambient, sc.ambient[0])
        channels = (0,) if grey else (0, 1, 2)
        light = [sc.ambient[c] + sum(diffuse[j, c] * cosines[j] for j in range(len(cosines)))
                 for c in channels]
        if grey:  # one intensity for the three channels (dm_control's lights are white)
            light = light * 3
        return [jnp.clip(colour[c] * light[c], 0.0, 1.0) for c in range(3)]

    def _light_vectors(self, poses) -> jax.Array:
        """``(1 + L, 3)`` unit vectors toward the headlight (which shines along the view
        direction) and each model light (treated as directional), in camera coordinates."""
        sc = self.scene
        head = jnp.asarray([[0.0, 0.0, 1.0]], jnp.float32)
        if sc.light_dirs.shape[0] == 0:
            return head
        world_dirs = jnp.einsum("lij,lj->li", poses["light_body_mat"], jnp.asarray(sc.light_dirs))
        world_dirs = world_dirs / jnp.linalg.norm(world_dirs, axis=-1, keepdims=True)
        return jnp.concatenate([head, -world_dirs @ poses["cam_mat"]], axis=0)

    def _sky(self, cam_mat) -> list[jax.Array]:
        """``[3 x (H, W)]`` background: the skybox gradient over world elevation, or a flat
        colour."""
        sc, cfg = self.scene, self.config
        h, w = cfg.height, cfg.width
        if cfg.sky == "color":
            return [jnp.full((h, w), c, jnp.float32) for c in cfg.background_color]
        x = jnp.asarray(self._x)
        y = jnp.asarray(self._y)
        inv_len = jax.lax.rsqrt(x * x + y * y + 1.0)
        z = (x * cam_mat[2, 0] + y * cam_mat[2, 1] - cam_mat[2, 2]) * inv_len
        return [jnp.clip(sc.sky_mid[c] + sc.sky_slope[c] * z, 0.0, 1.0) for c in range(3)]


def _shift(a, axis: int, step: int, fill):
    """``out[i] = a[i + step]`` along ``axis`` (``step`` = +-1), ``fill`` past the edge."""
    n = a.shape[axis]
    pad = jnp.full_like(jax.lax.slice_in_dim(a, 0, 1, axis=axis), fill)
    if step > 0:
        return jnp.concatenate([jax.lax.slice_in_dim(a, 1, n, axis=axis), pad], axis=axis)
    return jnp.concatenate([pad, jax.lax.slice_in_dim(a, 0, n - 1, axis=axis)], axis=axis)


def _surface_step(depth, best, x, y, pixel: float, axis: int):
    """Tangent ``[3 x (H, W)]`` along ``axis`` (columns: 1, rows: 0) between the hit points
    ``depth * (x, y, -1)`` of neighbouring pixels on the same geom: the forward or backward
    difference with the smaller depth step; where neither neighbour is on the same geom, a
    step of one pixel along the image axis at the pixel's depth. ``pixel`` is the pixel
    pitch in image coordinates (positive along columns, negative along rows)."""
    depth_ahead = _shift(depth, axis, 1, 0.0)
    depth_behind = _shift(depth, axis, -1, 0.0)
    same_ahead = _shift(best, axis, 1, -1) == best
    same_behind = _shift(best, axis, -1, -1) == best
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


def _cross(u, v):
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


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
