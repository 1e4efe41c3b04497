"""The ray-cast RGB-D camera: one ``mjx.Data`` -> an RGB image and a depth map.

How it works (and why, on a CPU):

- Geometry moves into the camera frame once per image: pixel ``(x, y)``'s ray is
  ``t * (x, y, -1)``, so the ray parameter ``t`` *is* the depth along the optical axis, and
  each geom's local ray direction is an affine function of ``(x, y)``. Intersections are
  closed forms per primitive (``intersect.py``), unrolled over the geoms (types and sizes are
  static).
- The nearest hit is one ``min`` over int32 keys that pack the depth and the geom index
  (``Camera._key``): no argmin, no per-geom payloads.
- Types with many geoms (cheetah's capsules) are culled per screen tile: only the (tile, geom)
  pairs where the geom's projected bounds reach the tile are traced, from a fixed-size list
  (``cull_pairs_per_tile``); a batch chunk with more pairs than that is traced densely
  instead, so the result never depends on the culling.
- Shading needs no per-geom work per pixel: colour by geom index, Lambert normals from the
  hit points of neighbouring pixels on the same geom, the floor checker from the plane's hit
  coordinates, the sky from the ray's elevation (or a skybox texture by ray direction,
  ``sky.py``), partly transparent geoms blended over it.
- Under ``vmap`` the batch is rendered in chunks (``batch_chunk`` images per step of a loop)
  so intermediates stay in cache; see ``Camera._batchable``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Optional

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from iap_mjx import chunks
from iap_mjx.render import intersect
from iap_mjx.render import scene as scene_lib
from iap_mjx.render import sky as sky_lib

SHADINGS = ("lambert", "flat")
SKIES = ("skybox", "color")


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """Static settings of a camera (hashable).

    Attributes:
      camera_id: index into the model's cameras (``-1`` is not supported: use a model camera).
      height, width: image size in pixels.
      geom_groups: geom groups drawn (MuJoCo's renderer shows 0, 1, 2 by default).
      shading: ``"lambert"`` (ambient + headlight + the model's directional, spot and point
        lights, without shadows, specular, emission or attenuation)
        or ``"flat"`` (the geom colour as is).
      sky: where no geom is hit: ``"skybox"`` (a vertical gradient fitted to the model's skybox
        texture) or ``"color"`` (``background_color``). A per-call ``background`` image given
        to ``render`` replaces either.
      background_color: RGB in [0, 1] for ``sky="color"``.
      checker_floor: draw textured planes as dm_control's 2x2 checker (else flat material colour).
      batch_chunk: under ``vmap``, images rendered together per step of the loop over the batch
        (small enough for the intermediates to stay in cache); ``None`` (default):
        ``40,000 // pixels`` per image, between 1 and 4 (4 up to 10,000 pixels, 1 above
        20,000).
      tile: side in pixels of the square screen tiles used for culling.
      cull_pairs_per_tile: budget of (tile, geom) pairs per culled type group, per tile on
        average (types with at least 3 geoms, planes excepted, are traced only on the tiles
        their projected bounds reach). A batch chunk whose pairs exceed the budget is traced
        densely instead, so results never depend on it; 0 turns culling off.
    """

    camera_id: int = 0
    height: int = 100
    width: int = 100
    geom_groups: tuple[int, ...] = (0, 1, 2)
    shading: str = "lambert"
    sky: str = "skybox"
    background_color: tuple[float, float, float] = (0.0, 0.0, 0.0)
    checker_floor: bool = True
    batch_chunk: Optional[int] = None
    tile: int = 10
    cull_pairs_per_tile: float = 1.0

    def __post_init__(self):
        if not isinstance(self.camera_id, int) or self.camera_id < 0:
            raise ValueError(f"camera_id must be an int >= 0 (a model camera), got {self.camera_id!r}")
        for name in ("height", "width"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        if not (isinstance(self.geom_groups, (tuple, list))
                and all(isinstance(g, int) and 0 <= g < 6 for g in self.geom_groups)):
            raise ValueError(f"geom_groups must be a tuple of ints in 0..5, got {self.geom_groups!r}")
        if not isinstance(self.tile, int) or self.tile < 1:
            raise ValueError(f"tile must be a positive int, got {self.tile!r}")
        if (not isinstance(self.cull_pairs_per_tile, (int, float))
                or not math.isfinite(self.cull_pairs_per_tile) or self.cull_pairs_per_tile < 0):
            raise ValueError(f"cull_pairs_per_tile must be a finite number >= 0, got {self.cull_pairs_per_tile!r}")
        if self.batch_chunk is None:
            object.__setattr__(self, "batch_chunk", max(1, min(4, 40_000 // (self.height * self.width))))
        if not isinstance(self.batch_chunk, int) or self.batch_chunk < 1:
            raise ValueError(f"batch_chunk must be a positive int or None, got {self.batch_chunk!r}")
        if self.shading not in SHADINGS:
            raise ValueError(f"shading must be one of {SHADINGS}, got {self.shading!r}")
        if self.sky not in SKIES:
            raise ValueError(f"sky must be one of {SKIES}, got {self.sky!r}")
        if not (isinstance(self.background_color, (tuple, list)) and len(self.background_color) == 3
                and all(isinstance(c, (int, float)) and 0 <= c <= 1 for c in self.background_color)):
            raise ValueError(f"background_color must be 3 numbers in [0, 1], got {self.background_color!r}")
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
        ``self.zfar`` (finite, so depth is safe to feed to a network);
      - there is no near plane: a surface closer than ``vis.map.znear * extent``, which
        MuJoCo's renderer clips away, is drawn (as ``mj_ray`` sees it); surfaces are seen
        from outside only (a camera inside a geom does not see that geom).
    """

    def __init__(self, mj_model: mujoco.MjModel, camera_id: int = 0, height: int = 100,
                 width: int = 100, **config):
        self.config = CameraConfig(camera_id=camera_id, height=height, width=width, **config)
        if camera_id >= mj_model.ncam:
            raise ValueError(f"camera_id must be < the model's ncam={mj_model.ncam}, got {camera_id}")
        _check_projection(mj_model, camera_id, height, width)
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
        self._identity = (self.config, self.scene.digest(), self.fovy)
        self._kernels = {}
        self._setup_tiles(half_w, half_h)
        n_tiles = self._tile_x.shape[0]
        self._pair_budget = int(np.ceil(self.config.cull_pairs_per_tile * n_tiles))
        groups = {}
        for k, gtype in enumerate(self.scene.geom_type):
            groups.setdefault(int(gtype), []).append(k)
        self._culled_groups = tuple(
            (gtype, tuple(members)) for gtype, members in sorted(groups.items())
            if gtype != scene_lib.PLANE and self._pair_budget > 0 and len(members) >= 3)
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
        self._grid_x = cols[None, :].astype(np.float32)  # (1, nx * tw)
        self._grid_y = rows[:, None].astype(np.float32)  # (ny * th, 1)
        self._tile_bounds = np.stack([self._tile_x.min(1), self._tile_x.max(1),
                                      self._tile_y.min(1), self._tile_y.max(1)], axis=1)

    def __hash__(self) -> int:
        return hash(self._identity)

    def __eq__(self, other) -> bool:
        return isinstance(other, Camera) and self._identity == other._identity

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
               geom_rgb: Optional[jax.Array] = None,
               sky_texture: Optional[jax.Array | tuple[jax.Array, jax.Array]] = None,
               ) -> tuple[jax.Array, jax.Array]:
        """Renders one state (``vmap`` it for a batch); :meth:`render_ids` also returns the
        geom seen at each pixel.

        Args:
          data: an ``mjx.Data`` after kinematics (``geom_xpos``, ``geom_xmat``, ``cam_xpos``,
            ``cam_xmat``; ``xpos``, ``xmat``, ``subtree_com`` of the lights' bodies).
          background: optional ``(H, W, 3)`` float image in [0, 1] shown where nothing is hit
            (e.g. a Distracting Control Suite frame); replaces the sky.
          geom_rgb: optional ``(G, 3)`` colours replacing the model's (colour perturbations),
            one row per ``self.geom_ids`` entry; a checker floor's texture is multiplied by
            its row, as MuJoCo tints a texture by the material colour.
          sky_texture: optional skybox face (a Distracting Control Suite video frame),
            ``(S, S, 3)`` uint8 or already packed by ``sky.pack_rgb`` (``(S * S,)`` int32, as
            the distraction layer keeps its frames), seen by ray direction on every face of
            the cube as MuJoCo draws a square skybox texture (``sky.py``); replaces the sky
            (``background`` wins). Or a pair ``(stack, row)``: packed frames ``(N, S * S)``
            int32 and the ``()`` int32 row shown, clamped to ``[0, N)`` (under ``vmap``, an
            unbatched stack is read in place, never copied per image).

        Returns:
          rgb ``(H, W, 3)`` float32 in [0, 1] and depth ``(H, W)`` float32 in metres.
        """
        rgb, depth, _ = self.render_ids(data, background, geom_rgb, sky_texture)
        return rgb, depth

    def render_ids(self, data: mjx.Data, background: Optional[jax.Array] = None,
                   geom_rgb: Optional[jax.Array] = None,
                   sky_texture: Optional[jax.Array | tuple[jax.Array, jax.Array]] = None,
                   ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """:meth:`render`'s rgb and depth, and the hit geom's MuJoCo id ``(H, W)`` int32
        (``-1`` where nothing is hit) from the same trace (one program, not two)."""
        cfg = self.config
        if background is None:
            background = jnp.zeros((0,), jnp.float32)
        elif (tuple(background.shape) != (cfg.height, cfg.width, 3)
              or not jnp.issubdtype(background.dtype, jnp.floating)):
            raise ValueError(f"background must be floats in [0, 1] of shape {(cfg.height, cfg.width, 3)}, "
                             f"got {background.dtype} {background.shape}")
        if geom_rgb is None:
            geom_rgb = jnp.zeros((0,), jnp.float32)
        elif tuple(geom_rgb.shape) != (len(self.scene.geom_ids), 3):
            raise ValueError(
                f"geom_rgb must have shape {(len(self.scene.geom_ids), 3)}, got {geom_rgb.shape}")
        sky_frame = None
        if isinstance(sky_texture, (tuple, list)):
            sky_texture, sky_frame = sky_texture
            if not (sky_texture.ndim == 2 and sky_texture.dtype == jnp.int32
                    and math.isqrt(sky_texture.shape[1]) ** 2 == sky_texture.shape[1] > 0
                    and sky_texture.size < 2**31):
                raise ValueError("sky_texture (stack, row): the stack must be packed frames "
                                 "(N, S * S) int32 (fewer than 2**31 texels), got "
                                 f"{sky_texture.dtype} {sky_texture.shape}")
            if jnp.shape(sky_frame) != ():
                raise ValueError(f"sky_texture (stack, row): the row must be a scalar int, got shape "
                                 f"{jnp.shape(sky_frame)}")
            # clamped: the texel gather trusts its indices (a row past the stack reads past it)
            sky_frame = jnp.clip(jnp.asarray(sky_frame, jnp.int32), 0, sky_texture.shape[0] - 1)
        elif sky_texture is None:
            sky_texture = jnp.zeros((0, 1), jnp.int32)
        elif (sky_texture.ndim == 3 and sky_texture.shape[0] == sky_texture.shape[1]
              and sky_texture.shape[2] == 3 and sky_texture.dtype == jnp.uint8):
            sky_texture = sky_lib.pack_rgb(sky_texture)[None]
        elif (sky_texture.ndim == 1 and sky_texture.dtype == jnp.int32
              and math.isqrt(sky_texture.shape[0]) ** 2 == sky_texture.shape[0] > 0):
            sky_texture = sky_texture[None]
        else:
            raise ValueError("sky_texture must be (S, S, 3) uint8 or packed (S * S,) int32 (or a "
                             f"pair (stack (N, S * S), row)), got {sky_texture.dtype} {sky_texture.shape}")
        if sky_frame is None:
            sky_frame = jnp.zeros((), jnp.int32)
        return self._batchable(True)(self._poses(data), background, geom_rgb, sky_texture, sky_frame)

    def trace(self, data: mjx.Data) -> tuple[jax.Array, jax.Array]:
        """Geometry only: depth ``(H, W)`` float32 (far plane where nothing is hit) and the
        hit geom's MuJoCo id ``(H, W)`` int32 (``-1`` where nothing is hit)."""
        empty = jnp.zeros((0,), jnp.float32)
        _, depth, ids = self._batchable(False)(self._poses(data), empty, empty,
                                               jnp.zeros((0, 1), jnp.int32), jnp.zeros((), jnp.int32))
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
            "light_body_pos": data.xpos[jnp.asarray(sc.light_bodyid)],
            "light_body_mat": data.xmat[jnp.asarray(sc.light_bodyid)],
            "light_body_com": data.subtree_com[jnp.asarray(sc.light_bodyid)],
            **({"light_target_pos": data.xpos[jnp.asarray(sc.light_targetbodyid)],
                "light_target_com": data.subtree_com[jnp.asarray(sc.light_targetbodyid)]}
               if np.any(sc.light_mode >= 3) else {}),
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

        def single(poses, background, geom_rgb, sky_texture, sky_frame):
            return self._program(poses, background, geom_rgb, sky_texture, sky_frame, colour,
                                 batched=False)

        batched = jax.custom_batching.custom_vmap(single)

        @batched.def_vmap
        def _rule(axis_size, in_batched, poses, background, geom_rgb, sky_texture, sky_frame):
            # an unbatched sky stack is shared by every chunk as it is (not broadcast per image)
            shared_sky = not in_batched[3]
            per_image = (poses, background, geom_rgb, sky_frame) + (() if shared_sky else (sky_texture,))
            flags = tuple(in_batched[:3]) + (in_batched[4],) + (() if shared_sky else (True,))
            args = jax.tree.map(
                lambda x, b: x if b else jnp.broadcast_to(x, (axis_size,) + x.shape), per_image, flags)
            def one_chunk(a):
                sky = sky_texture if shared_sky else a[4]
                return self._program(a[0], a[1], a[2], sky, a[3], colour, batched=True)

            out = chunks.map_chunks(one_chunk, args, self.config.batch_chunk, axis_size)
            return out, jax.tree.map(lambda _: True, out)

        self._kernels[colour] = batched
        return batched

    def _program(self, poses, background, geom_rgb, sky_texture, sky_frame, colour: bool,
                 batched: bool):
        """One image, or (``batched``) a leading axis of images: ``(rgb (H, W, 3) or None,
        depth (H, W), geom id (H, W))``. Culled tracing first; if any image of the batch has
        more (tile, geom) pairs than the budget, dense tracing.

        The trace ends in a ``lax.cond`` (on some camera pose of the batch being finite): its
        results are materialised once, where XLA would otherwise fuse the nearest-hit
        selection into every shading consumer and redo it many times. An image whose camera
        pose is not finite sees nothing (depth ``zfar``, id ``-1``, black), whatever the other
        images of its batch.
        """
        lift = jax.vmap if batched else (lambda f: f)
        frames = lift(self._frames)(poses)
        seen = (jnp.all(jnp.isfinite(poses["cam_pos"]), axis=-1)
                & jnp.all(jnp.isfinite(poses["cam_mat"]), axis=(-2, -1)))  # () or (C,) per image
        finite = jnp.any(seen)
        shape = jnp.shape(poses["cam_pos"])[:-1] + (self.config.height, self.config.width)

        def nothing():
            # derived from an input, so it carries the same sharding type under shard_map
            zero = 0.0 * jnp.nan_to_num(poses["cam_pos"][..., 0])[..., None, None]
            return (jnp.broadcast_to(zero + self.scene.zfar, shape),
                    jnp.broadcast_to(zero.astype(jnp.int32) + len(self.scene.geom_ids), shape))

        def padded_of(trace):
            return lambda: lift(_pad_one)(trace())

        # Each stage runs inside a ``lax.cond`` on ``finite`` (the other branch gives zeros):
        # its results are materialised once, where XLA would otherwise fuse the nearest-hit
        # selection, or the shading, into every consumer (and the interleaved (H, W, 3) output
        # per channel) and redo it many times. Computed inside the branch, a stage writes its
        # outputs directly (a cond passing through values computed outside copies them).
        def dense():
            # the nearest-hit keys materialised first (fused into the padded outputs, the
            # search over all geoms would run once per output element and per output)
            keys = self._stage(lambda: lift(self._dense_keys)(frames), finite)
            return lift(_pad_one)(lift(self._decode)(keys))

        if self._culled_groups:
            keys, overflow = lift(self._trace_culled_keys)(frames)
            depth_p, best_p = jax.lax.cond(
                jnp.any(overflow & seen) | ~finite,
                lambda: jax.lax.cond(finite, dense, padded_of(nothing)),
                padded_of(lambda: lift(self._decode_image)(keys)))
        else:
            depth_p, best_p = jax.lax.cond(finite, dense, padded_of(nothing))
        # a non-finite image of a traced batch: nothing seen (its own trace, a search with NaN
        # or inf poses, is not relied on)
        seen_px = seen[..., None, None]
        depth = jnp.where(seen_px, depth_p[..., 1:-1, 1:-1], jnp.float32(self.scene.zfar))
        best = best_p[..., 1:-1, 1:-1].astype(jnp.int32)
        ids = jnp.where(seen_px, jnp.asarray(np.append(self.scene.geom_ids, -1).astype(np.int32))[best], -1)
        if not colour:
            return None, depth, ids
        # Neighbour lookups read slices of the padded planes (no concatenates, which XLA's
        # CPU loops do not vectorise). The light (normals, lights) and a skybox texture's
        # texels are materialised, then the colour and composition in planes (fused into the
        # interleaved output they would run per element, unvectorised).
        padded = (depth_p, best_p)
        if self.config.shading == "flat":
            light = (jnp.ones_like(depth),)
        else:
            light = self._stage(lambda: lift(self._light)(poses, padded), finite)
        if background.size == 0 and sky_texture.size != 0:
            # a non-finite pose's directions would index outside the texture stack
            safe_mat = jnp.where(seen[..., None, None], poses["cam_mat"], 0.0)
            texels = self._stage(lambda: self._skybox(safe_mat, sky_texture, sky_frame), finite)
            background = tuple(sky_lib.unpack_rgb(texels))
        planes = self._stage(lambda: lift(self._compose)(
            poses, lift(self._colour)(frames, padded, geom_rgb), light, best_p, background), finite)
        return jnp.where(seen_px[..., None], jnp.stack(planes, axis=-1), 0.0), depth, ids

    @staticmethod
    def _stage(fn, pred):
        """``fn()`` computed inside a ``lax.cond`` on ``pred`` (which should hold; otherwise
        zeros of the same shapes), so that its outputs are materialised."""
        shapes = jax.eval_shape(fn)

        def zeros():
            zero = jnp.where(pred, 0, 0)  # carries pred's sharding type under shard_map
            return jax.tree.map(lambda s: jnp.broadcast_to(zero.astype(s.dtype), s.shape), shapes)

        return jax.lax.cond(pred, fn, zeros)

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

    def _dense_keys(self, frames):
        """Every geom against every pixel: the nearest-hit keys (``_key``) ``(H, W)``."""
        x, y = jnp.asarray(self._x), jnp.asarray(self._y)
        r_cam, origin = frames["r_cam"], frames["origin"]
        shape = (self.config.height, self.config.width)
        keys = [self._far_key(shape)] + [
            jnp.broadcast_to(self._key(self._intersect_static(k, r_cam, origin, x, y), k), shape)
            for k in range(len(self.scene.geom_ids))]
        return jnp.min(jnp.stack(keys), axis=0)

    def _decode_image(self, keys):
        """Keys of the image padded to whole tiles -> depth and geom index ``(H, W)``."""
        cfg = self.config
        return self._decode(keys[: cfg.height, : cfg.width])

    def _trace_culled_keys(self, frames):
        """Planes and small type groups against every pixel; each culled type group only
        against the tiles its geoms' projected bounds reach: the (tile, geom) pairs are listed
        (at most ``self._pair_budget`` per group), each pair traces its tile's pixels, and a
        scatter-min of the tile windows merges them. Returns the nearest-hit keys (``_key``)
        ``(ny * th, nx * tw)`` (the image padded to whole tiles) and ``overflow``, true if a
        group had more pairs than the budget (the result is then incomplete and the caller
        falls back to ``_dense_keys``)."""
        sc = self.scene
        ny, nx, th, tw = self._tile_grid
        gx, gy = jnp.asarray(self._grid_x), jnp.asarray(self._grid_y)
        tx, ty = jnp.asarray(self._tile_x), jnp.asarray(self._tile_y)
        r_cam, origin = frames["r_cam"], frames["origin"]
        shape = (ny * th, nx * tw)
        keys = jnp.min(jnp.stack(
            [self._far_key(shape)]
            + [jnp.broadcast_to(self._key(self._intersect_static(k, r_cam, origin, gx, gy), k), shape)
               for k in self._dense_geoms]),
            axis=0)
        overflow = jnp.zeros((), bool)
        budget = self._pair_budget
        windows = jax.lax.ScatterDimensionNumbers(
            update_window_dims=(1, 2), inserted_window_dims=(), scatter_dims_to_operand_dims=(0, 1))
        for gtype, members in self._culled_groups:
            members_arr = jnp.asarray(members, jnp.int32)
            overlap = self._tile_overlap(frames, members).reshape(-1)  # tile-major pairs
            overflow |= jnp.sum(overlap) > budget
            pair, valid = _first_pairs(overlap, budget)
            tile, local = pair // len(members), pair % len(members)
            params = jnp.concatenate([
                r_cam[members_arr, 0, :], r_cam[members_arr, 1, :], -r_cam[members_arr, 2, :],
                origin[members_arr], jnp.asarray(sc.geom_size[list(members)]),
            ], axis=1)[local]
            col = [params[:, i: i + 1] for i in range(15)]
            px, py = tx[tile], ty[tile]
            d = tuple(px * col[i] + py * col[3 + i] + col[6 + i] for i in range(3))
            t = intersect.BY_TYPE[gtype](tuple(col[9:12]), d, tuple(col[12:15]))
            pair_keys = jnp.where(valid[:, None], self._key(t, members_arr[local][:, None]),
                                  jnp.iinfo(jnp.int32).max)
            corner = jnp.stack([tile // nx * th, tile % nx * tw], axis=1)  # (budget, 2)
            keys = jax.lax.scatter_min(keys, corner, pair_keys.reshape(budget, th, tw), windows,
                                       indices_are_sorted=True,
                                       mode=jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS)
        return keys, overflow

    def _tile_overlap(self, frames, members):
        """``(tiles, len(members))`` bool: may the geom cover a pixel centre of the tile?
        Each geom is bounded by one sphere, or (capsule, cylinder) by the convex hull of its
        two end spheres (the capsule, which holds the cylinder); each sphere by a conservative
        box in image coordinates ``x / -z, y / -z``, and the hull by the box around its
        spheres' boxes (in front of the camera, a convex hull projects into the hull of the
        projections); a geom reaching the camera plane covers everything."""
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
        # a sphere within 1e-6 m of the camera plane counts as reaching it (its projected
        # box would be unbounded); boxes grow by 1e-4 in image coordinates (about 1e-4 rad,
        # far above the float32 rounding of the bounds) so rounding never culls a hit
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

    @property
    def _index_mask(self) -> int:
        return (1 << max(1, len(self.scene.geom_ids).bit_length())) - 1

    def _key(self, t, k):
        """int32 key of a hit at ray parameter ``t`` on geom index ``k``.

        A positive float's bits order like its value, so replacing the depth's low mantissa
        bits by the geom index gives keys whose minimum is the nearest hit *and* names its
        geom (the depth loses those bits: a relative error below ``2**(bits - 23)``, under
        1e-5 for up to 63 geoms). One ``min`` then replaces an argmin with payloads.
        """
        bits = jax.lax.bitcast_convert_type(jnp.maximum(t, 0.0), jnp.int32)
        return (bits & ~self._index_mask) | k

    def _far_key(self, shape):
        """Keys of 'nothing before the far plane' (index ``G``)."""
        zfar_bits = int(np.float32(self.scene.zfar).view(np.int32))
        return jnp.full(shape, (zfar_bits & ~self._index_mask) | len(self.scene.geom_ids), jnp.int32)

    def _decode(self, keys):
        """Keys -> depth (far plane where nothing is hit) and geom index (``G`` if none)."""
        n_geom = len(self.scene.geom_ids)
        index = keys & self._index_mask
        depth = jax.lax.bitcast_convert_type(keys & ~self._index_mask, jnp.float32)
        return jnp.where(index == n_geom, jnp.float32(self.scene.zfar), depth), index

    def _compose(self, poses, surface, light, best_p, background):
        """``3 x (H, W)`` image planes: lit surface where a geom is hit, else the background
        (``best_p``: the padded float geom index of ``_pad_one``)."""
        best = best_p[1:-1, 1:-1]
        if isinstance(background, (tuple, list)):  # the skybox planes of ``_skybox``
            background = list(background)
        elif background.size == 0:
            background = self._sky(poses["cam_mat"])
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

    def _skybox(self, cam_mat, sky_texture, sky_frame) -> jax.Array:
        """``([C,] H, W)`` int32 packed texels of frame ``sky_frame`` ``([C])`` of the stack
        ``sky_texture`` (``(N, S * S)`` shared, or ``(C, N, S * S)`` one stack per image) by
        world ray direction (``cam_mat`` ``([C,] 3, 3)``): one gather for a whole chunk."""
        if sky_texture.ndim == 3:  # one stack per image: rows of the stacks laid end to end
            n = sky_texture.shape[1]
            sky_frame = jnp.arange(sky_texture.shape[0], dtype=jnp.int32) * n + sky_frame
            sky_texture = sky_texture.reshape(-1, sky_texture.shape[-1])
        x = jnp.asarray(self._x)
        y = jnp.asarray(self._y)
        m = cam_mat[..., None, None]  # (..., 3, 3, 1, 1) against (H, 1) and (1, W)
        dx, dy, dz = (x * m[..., i, 0, :, :] + y * m[..., i, 1, :, :] - m[..., i, 2, :, :] for i in range(3))
        size = math.isqrt(int(sky_texture.shape[-1]))
        return sky_lib.skybox_texels(sky_texture, sky_frame, size, dx, dy, dz)

    def _colour(self, frames, padded, geom_rgb):
        """Surface colour ``3 x (H, W)`` of each pixel's nearest geom: the geom's, or the
        checker floor's at the hit point (``padded``: depth and geom index with a one-pixel
        border, ``_pad_one``)."""
        rgb_table = self.scene.geom_rgb if geom_rgb.size == 0 else geom_rgb.astype(jnp.float32)
        sc = self.scene
        depth_p, best_p = padded
        depth, best = depth_p[1:-1, 1:-1], best_p[1:-1, 1:-1]
        x, y = jnp.asarray(self._x), jnp.asarray(self._y)
        colour = [jnp.zeros_like(depth) for _ in range(3)]
        for k in range(len(sc.geom_ids)):
            mine = best == k
            colour = [jnp.where(mine, rgb_table[k, c], colour[c]) for c in range(3)]
        if self.config.checker_floor:
            r_cam, origin = frames["r_cam"], frames["origin"]
            for k in np.flatnonzero(sc.checker):
                u = origin[k, 0] + depth * (x * r_cam[k, 0, 0] + y * r_cam[k, 1, 0] - r_cam[k, 2, 0])
                v = origin[k, 1] + depth * (x * r_cam[k, 0, 1] + y * r_cam[k, 1, 1] - r_cam[k, 2, 1])
                squares = [c * sc.checker_scale[k, i] for i, c in enumerate((u, v))]
                squares = [c + sc.checker_offset[k, i] if sc.checker_offset[k, i] else c
                           for i, c in enumerate(squares)]
                odd = ((_floor_int(squares[0]) + _floor_int(squares[1])) & 1) == 1
                mine = best == k
                if geom_rgb.size == 0:
                    tints = [sc.checker_rgb[k, :, c] for c in range(3)]
                else:  # MuJoCo multiplies the texture by the (changed) colour
                    tints = [sc.checker_texture[k, :, c] * rgb_table[k, c] for c in range(3)]
                colour = [jnp.where(mine, jnp.where(odd, tints[c][1], tints[c][0]), colour[c])
                          for c in range(3)]
        return tuple(colour)

    def _light(self, poses, padded):
        """The light falling on each pixel's surface, ``1 x (H, W)`` when all lights are grey
        (dm_control's are) else ``3 x (H, W)`` (``padded`` as in :meth:`_colour`).

        The normal for Lambert shading comes from the hit points of neighbouring pixels on
        the same geom (the one-sided difference with the smaller depth step, so edges do not
        bend it), which needs no per-geom work per pixel.
        """
        sc = self.scene
        depth_p, best_p = padded
        depth = depth_p[1:-1, 1:-1]
        x, y = jnp.asarray(self._x), jnp.asarray(self._y)
        tangent_x = _surface_step(depth_p, best_p, x, y, self._pixel_pitch[0], axis=1)
        tangent_y = _surface_step(depth_p, best_p, x, y, -self._pixel_pitch[1], axis=0)
        normal = _cross(tangent_x, tangent_y)
        # < 0 when facing the camera (the hit point is depth * (x, y, -1))
        facing = normal[0] * x + normal[1] * y - normal[2]
        normal = [jnp.where(facing > 0, -n, n) for n in normal]
        inv_len = jax.lax.rsqrt(jnp.maximum(sum(n * n for n in normal), 1e-30))
        position, direction = self._lights(poses)
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
            falloff = (jax.lax.integer_pow(jnp.maximum(spot, 0.0), int(exponent))
                       if exponent.is_integer() else jnp.maximum(spot, 0.0) ** exponent)
            cone = jnp.where(spot >= sc.light_cos_cutoff[j], falloff, 0.0)
            cosines.append(lit * cone)
        diffuse = np.concatenate([sc.headlight_diffuse[None], sc.light_diffuse], axis=0)
        grey = np.allclose(diffuse, diffuse[:, :1]) and np.allclose(sc.ambient, sc.ambient[0])
        channels = (0,) if grey else (0, 1, 2)
        light = [sc.ambient[c] + sum(diffuse[j, c] * cosines[j] for j in range(len(cosines)))
                 for c in channels]
        return tuple(light)

    def _lights(self, poses) -> tuple[jax.Array, jax.Array]:
        """Model lights in camera coordinates: positions ``(L, 3)`` and unit directions they
        shine along ``(L, 3)``, as MuJoCo's ``mj_camlight`` places them."""
        sc = self.scene
        if sc.light_mode.shape[0] == 0:
            return jnp.zeros((0, 3)), jnp.zeros((0, 3))
        mats = poses["light_body_mat"]
        offset = jnp.asarray(sc.light_offset)
        mode = sc.light_mode
        fixed = jnp.asarray((mode == 0) | (mode >= 3))[:, None]  # placed in the body frame
        world_pos = jnp.where(
            fixed, poses["light_body_pos"] + jnp.einsum("lij,lj->li", mats, offset),
            jnp.where(jnp.asarray(mode == 2)[:, None], poses["light_body_com"],
                      poses["light_body_pos"]) + offset)
        world_dir = jnp.where(fixed, jnp.einsum("lij,lj->li", mats, jnp.asarray(sc.light_dirs)),
                              jnp.asarray(sc.light_dirs))
        if np.any(mode >= 3):  # aimed at the target body (3) or its subtree's centre of mass (4)
            target = jnp.where(jnp.asarray(mode == 4)[:, None], poses["light_target_com"],
                               poses["light_target_pos"])
            world_dir = jnp.where(jnp.asarray(mode >= 3)[:, None], target - world_pos, world_dir)
        world_dir = world_dir / jnp.linalg.norm(world_dir, axis=-1, keepdims=True)
        cam_mat = poses["cam_mat"]
        return (world_pos - poses["cam_pos"]) @ cam_mat, world_dir @ cam_mat

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


def _check_projection(mj_model: mujoco.MjModel, camera_id: int, height: int, width: int) -> None:
    """Refuses model cameras this camera would draw differently from MuJoCo's renderer: it
    draws a perspective frustum from ``cam_fovy`` and the image's aspect ratio."""
    projection = int(mj_model.cam_projection[camera_id])
    if projection != int(mujoco.mjtProjection.mjPROJ_PERSPECTIVE):
        raise ValueError(f"camera_id={camera_id} has projection {mujoco.mjtProjection(projection).name}; "
                         "only perspective cameras (mjPROJ_PERSPECTIVE) are supported")
    sensor = np.asarray(mj_model.cam_sensorsize[camera_id], np.float64)
    if np.any(sensor > 0):  # intrinsics (focal, principal, sensorsize) set the frustum
        fx, fy, cx, cy = (float(v) for v in mj_model.cam_intrinsic[camera_id])
        if not (fx == fy and cx == 0 and cy == 0
                and math.isclose(sensor[0] / sensor[1], width / height, rel_tol=1e-6)):
            raise ValueError(
                f"camera_id={camera_id} has intrinsics (sensorsize {tuple(sensor)}, focal {(fx, fy)}, "
                f"principal {(cx, cy)}): supported only with equal focal lengths, principal (0, 0) "
                f"and width / height equal to the sensor's {sensor[0] / sensor[1]:.6g}, got {width}x{height}")


def _floor_int(a):
    """``floor(a)`` as int32 (a truncating conversion and a fix-up: vectorises on CPU, where
    ``jnp.floor`` may not)."""
    truncated = a.astype(jnp.int32)
    return truncated - (a < truncated.astype(a.dtype)).astype(jnp.int32)


def _first_pairs(overlap, budget: int):
    """The indices of the first ``budget`` true entries of ``overlap`` ``(P,)`` bool, in order,
    ``(budget,)`` int32, and which of those slots hold one (``(budget,)`` bool; empty slots
    hold ``P - 1``, so the list stays sorted, as the tile scatter promises XLA). Ranks come
    from a prefix sum done as two small triangular matmuls (exact for counts below 2**24; a
    sort-based ``top_k`` or XLA's ``cumsum`` costs several times more on CPU), then one
    scatter."""
    n = overlap.shape[0]
    row = next(r for r in (64, 32, 16, 8, 4, 2, 1) if n % r == 0)
    x = overlap.astype(jnp.float32).reshape(n // row, row)
    within = x @ jnp.asarray(np.triu(np.ones((row, row), np.float32)))  # inclusive, per row
    before = jnp.asarray(np.tril(np.ones((n // row,) * 2, np.float32), -1)) @ jnp.sum(x, axis=1)
    rank = (within + before[:, None]).reshape(n).astype(jnp.int32) - 1
    slot = jnp.where(overlap, rank, budget)  # past the end: dropped
    pair = jnp.full(budget, n - 1, jnp.int32).at[slot].set(jnp.arange(n, dtype=jnp.int32), mode="drop")
    return pair, jnp.arange(budget) < jnp.sum(overlap)


def _pad_one(depth_and_best):
    """Depth and geom index ``(H, W)`` with a one-pixel border (depth 0, geom -1: no
    neighbour), ``(H + 2, W + 2)``, both float32 (CPU loops that mix int32 tests into float
    math do not vectorise; geom indices are exact in float32)."""
    depth, best = depth_and_best
    return jnp.pad(depth, 1), jnp.pad(best.astype(jnp.float32), 1, constant_values=-1.0)


def _surface_step(depth_p, best_p, x, y, pixel: float, axis: int):
    """Tangent ``[3 x (H, W)]`` along ``axis`` (columns: 1, rows: 0) between the hit points
    ``depth * (x, y, -1)`` of neighbouring pixels on the same geom: the forward or backward
    difference with the smaller depth step; where neither neighbour is on the same geom, a
    step of one pixel along the image axis at the pixel's depth. ``depth_p``, ``best_p`` are
    padded by one pixel; ``pixel`` is the pixel pitch in image coordinates (positive along
    columns, negative along rows)."""
    def window(a, offset):
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


def _cross(u, v):
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
