"""The ray-cast RGB-D camera: one ``mjx.Data`` -> an RGB image and a depth map.

This module is the public camera: its config, ``render``/``render_ids``/``trace``, the
checks on their inputs, and how a batch is run. An image is made in two passes:

- ``tracing.py``: the geometry pass. Each pixel's ray against every geom, or (types with
  many geoms) only the geoms whose projected bounds reach its screen tile: the nearest hit's
  depth and geom index.
- ``shading.py``: the colour pass. Surface colour, lights, floor checker, sky or skybox,
  from the depth and geom index alone.

Under ``vmap`` the batch is rendered in chunks (``batch_chunk`` images per step of a loop) so
intermediates stay in cache (``Camera._chunked_over_batch``); each pass's results are
materialised once (``Camera._trace`` and ``Camera._shade``).

The module is one class and what it takes: ``CameraConfig`` and its checks, ``Camera``'s public
methods, the checks of their inputs, and the one program that joins the two passes and batches
them; the passes themselves are in ``tracing.py`` and ``shading.py``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from iap_mjx import chunks
from iap_mjx.checks import is_int, is_number, require_choice, require_int, require_number
from iap_mjx.render import scene as scene_lib
from iap_mjx.render import shading, tracing
from iap_mjx.render import sky as sky_lib

SHADINGS = ("lambert", "flat")
SKIES = ("skybox", "color")
CHUNK_PIXELS = 40_000
"""Pixels rendered together under ``vmap`` when ``batch_chunk`` is ``None``."""


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
        ``CHUNK_PIXELS // pixels`` per image, between 1 and 4 (4 up to 10,000 pixels, 1 above
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
    batch_chunk: int | None = None
    tile: int = 10
    cull_pairs_per_tile: float = 1.0

    def __post_init__(self):
        require_int("CameraConfig.camera_id", self.camera_id, 0)
        for name in ("height", "width", "tile"):
            require_int(f"CameraConfig.{name}", getattr(self, name))
        if not (
            isinstance(self.geom_groups, (tuple, list)) and all(is_int(g) and 0 <= g < 6 for g in self.geom_groups)
        ):
            raise ValueError(f"CameraConfig.geom_groups must be a tuple of ints in 0..5, got {self.geom_groups!r}.")
        require_number("CameraConfig.cull_pairs_per_tile", self.cull_pairs_per_tile, 0, high_open=True)
        if self.batch_chunk is None:
            object.__setattr__(self, "batch_chunk", max(1, min(4, CHUNK_PIXELS // (self.height * self.width))))
        require_int("CameraConfig.batch_chunk", self.batch_chunk)
        require_choice("CameraConfig.shading", self.shading, SHADINGS)
        require_choice("CameraConfig.sky", self.sky, SKIES)
        if not (
            isinstance(self.background_color, (tuple, list))
            and len(self.background_color) == 3
            and all(is_number(c) and 0 <= c <= 1 for c in self.background_color)
        ):
            raise ValueError(
                f"CameraConfig.background_color must be 3 numbers in [0, 1], got {self.background_color!r}."
            )
        object.__setattr__(self, "geom_groups", tuple(self.geom_groups))
        object.__setattr__(self, "background_color", tuple(float(c) for c in self.background_color))


class _Traced(NamedTuple):
    """What :meth:`Camera._trace` hands the colour pass, per image (a leading axis when
    batched): the geoms' frames ``geom_frames`` (:class:`~iap_mjx.render.tracing.GeomFrames`),
    ``seen`` ``()`` bool (the camera pose is finite) and its ``(..., 1, 1)`` broadcast
    ``seen_px``, ``any_seen`` ``()`` bool (some image of the batch is seen), the padded planes
    ``(depth_p, best_p)`` ``(H + 2, W + 2)`` float32, and the image's ``depth`` float32 and
    geom ``ids`` int32 ``(H, W)``."""

    geom_frames: tracing.GeomFrames
    seen: jax.Array
    seen_px: jax.Array
    any_seen: jax.Array
    padded: tuple[jax.Array, jax.Array]
    depth: jax.Array
    ids: jax.Array


class Camera:
    """A ray-cast RGB-D camera for one model camera.

    ``Camera(mj_model, camera_id=0, height=100, width=100, **config)`` reads the static scene
    (geom types, sizes, colours, lights) once; ``render(data)`` is pure and works under
    ``jit`` and ``vmap``. A camera is hashable (by its config and scene content), so it can be
    a static argument or live inside a hashable env. ``tracer`` (``tracing.Tracer``) and
    ``shader`` (``shading.Shader``) hold the two passes over the same pixel rays.

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

    def __init__(self, mj_model: mujoco.MjModel, camera_id: int = 0, height: int = 100, width: int = 100, **config):
        self.config = CameraConfig(camera_id=camera_id, height=height, width=width, **config)
        if camera_id >= mj_model.ncam:
            raise ValueError(f"camera_id must be < the model's ncam={mj_model.ncam}, got {camera_id}")
        _check_projection(mj_model, camera_id, height, width)
        self.scene = scene_lib.build_scene(mj_model, self.config.geom_groups)
        self.fovy = float(mj_model.cam_fovy[camera_id])
        self.zfar = float(self.scene.zfar)
        self.tracer = tracing.Tracer(self.scene, self.config, self.fovy)
        self.shader = shading.Shader(self.scene, self.config, self.tracer.x, self.tracer.y, self.tracer.pixel_pitch)
        self._identity = (self.config, self.scene.digest(), self.fovy)
        self._programs: dict[Any, Any] = {}

    def __hash__(self) -> int:
        return hash(self._identity)

    def __eq__(self, other) -> bool:
        return isinstance(other, Camera) and self._identity == other._identity

    def __repr__(self) -> str:
        c = self.config
        return (
            f"Camera(camera_id={c.camera_id}, height={c.height}, width={c.width}, "
            f"geoms={len(self.scene.geom_ids)}, shading={c.shading!r})"
        )

    @property
    def geom_ids(self) -> np.ndarray:
        """``(G,)`` the MuJoCo ids of the geoms this camera draws."""
        return self.scene.geom_ids

    def ray_directions(self) -> np.ndarray:
        """``(H, W, 3)`` float32 pixel ray directions ``(x, y, -1)`` in the camera frame
        (not normalised: ``depth * direction`` is the hit point)."""
        h, w = self.config.height, self.config.width
        x = np.broadcast_to(self.tracer.x, (h, w))
        y = np.broadcast_to(self.tracer.y, (h, w))
        return np.stack([x, y, -np.ones((h, w), np.float32)], axis=-1)

    def render(
        self,
        data: mjx.Data,
        background: jax.Array | None = None,
        geom_rgb: jax.Array | None = None,
        sky_texture: jax.Array | tuple[jax.Array, jax.Array] | None = None,
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

    def render_ids(
        self,
        data: mjx.Data,
        background: jax.Array | None = None,
        geom_rgb: jax.Array | None = None,
        sky_texture: jax.Array | tuple[jax.Array, jax.Array] | None = None,
    ) -> tuple[jax.Array, jax.Array, jax.Array]:
        """:meth:`render`'s rgb and depth, and the hit geom's MuJoCo id ``(H, W)`` int32
        (``-1`` where nothing is hit) from the same trace (one program, not two)."""
        inputs = self._checked_inputs(background, geom_rgb, sky_texture)
        return self._chunked_over_batch(True)(self.poses(data), *inputs)

    def render_poses(self, poses: tracing.Poses) -> tuple[jax.Array, jax.Array]:
        """:meth:`render` (the model's colours and sky) of a state given by its :meth:`poses`:
        what an episode records to render some of its steps afterwards, a few hundred floats
        a step where its ``mjx.Data`` holds thousands."""
        rgb, depth, _ = self._chunked_over_batch(True)(poses, *self._checked_inputs(None, None, None))
        return rgb, depth

    def trace(self, data: mjx.Data) -> tuple[jax.Array, jax.Array]:
        """Geometry only: depth ``(H, W)`` float32 (far plane where nothing is hit) and the
        hit geom's MuJoCo id ``(H, W)`` int32 (``-1`` where nothing is hit)."""
        _, depth, ids = self._chunked_over_batch(False)(self.poses(data), *self._checked_inputs(None, None, None))
        return depth, ids

    # -- the inputs of render, as the program takes them -------------------------------------

    def _checked_inputs(
        self,
        background: jax.Array | None,
        geom_rgb: jax.Array | None,
        sky_texture: jax.Array | tuple[jax.Array, jax.Array] | None,
    ) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
        """:meth:`render`'s optional inputs as the program takes them: background, colours,
        sky stack and the row shown (empty arrays for none)."""
        background = self._checked_background(background)
        geom_rgb = self._checked_geom_rgb(geom_rgb)
        sky_texture, sky_frame = _sky_stack_and_row(sky_texture)
        return background, geom_rgb, sky_texture, sky_frame

    def _checked_background(self, background: jax.Array | None) -> jax.Array:
        """``background`` checked, or an empty array for none (the sky is drawn)."""
        cfg = self.config
        if background is None:
            return jnp.zeros((0,), jnp.float32)
        if tuple(background.shape) != (cfg.height, cfg.width, 3) or not jnp.issubdtype(background.dtype, jnp.floating):
            raise ValueError(
                f"background must be floats in [0, 1] of shape {(cfg.height, cfg.width, 3)}, "
                f"got {background.dtype} {background.shape}"
            )
        return background

    def _checked_geom_rgb(self, geom_rgb: jax.Array | None) -> jax.Array:
        """``geom_rgb`` checked, or an empty array for none (the model's colours)."""
        if geom_rgb is None:
            return jnp.zeros((0,), jnp.float32)
        if tuple(geom_rgb.shape) != (len(self.scene.geom_ids), 3):
            raise ValueError(f"geom_rgb must have shape {(len(self.scene.geom_ids), 3)}, got {geom_rgb.shape}")
        return geom_rgb

    # -- one image, and a batch of them -----------------------------------------------------

    def poses(self, data: mjx.Data) -> tracing.Poses:
        """The few per-state arrays the renderer reads (:meth:`render_poses`;
        :class:`~iap_mjx.render.tracing.Poses` gives each key's shape): the camera's pose
        ``(3,)`` and ``(3, 3)``, the drawn geoms' positions ``(G, 3)`` and orientations
        ``(G, 3, 3)``, and the positions ``(L, 3)``, orientations ``(L, 3, 3)`` and subtree
        centres of mass ``(L, 3)`` of the lights' bodies (and their targets', only if a light
        aims at one)."""
        sc = self.scene
        cam = self.config.camera_id
        gids = jnp.asarray(sc.geom_ids)
        poses: tracing.Poses = {
            "cam_pos": data.cam_xpos[cam],
            "cam_mat": data.cam_xmat[cam],
            "geom_pos": data.geom_xpos[gids],
            "geom_mat": data.geom_xmat[gids],
            "light_body_pos": data.xpos[jnp.asarray(sc.light_bodyid)],
            "light_body_mat": data.xmat[jnp.asarray(sc.light_bodyid)],
            "light_body_com": data.subtree_com[jnp.asarray(sc.light_bodyid)],
        }
        if sc.has_aimed_lights:
            poses["light_target_pos"] = data.xpos[jnp.asarray(sc.light_targetbodyid)]
            poses["light_target_com"] = data.subtree_com[jnp.asarray(sc.light_targetbodyid)]
        return poses

    def _chunked_over_batch(self, colour: bool):
        """:meth:`_trace_and_shade` of one image (``colour``: with the colour pass, else the
        geometry pass alone), wrapped so that ``vmap`` over a batch runs it as a loop over
        chunks of ``config.batch_chunk`` images (a ``vmap`` inside a ``lax.map``): each chunk's
        intermediates stay in cache, where one batch-wide pass per operation would leave it
        (``iap_mjx.chunks``); and the dense fallback of tile culling is a real branch taken
        only by chunks that need it. Built once per ``colour`` and kept."""
        cached = self._programs.get(colour)
        if cached is not None:
            return cached

        def single(
            poses: tracing.Poses,
            background: jax.Array,
            geom_rgb: jax.Array,
            sky_texture: jax.Array,
            sky_frame: jax.Array,
        ):
            return self._trace_and_shade(poses, background, geom_rgb, sky_texture, sky_frame, colour, batched=False)

        batched = jax.custom_batching.custom_vmap(single)

        @batched.def_vmap
        def _rule(axis_size, in_batched, poses: tracing.Poses, background, geom_rgb, sky_texture, sky_frame):
            # an unbatched sky stack is shared by every chunk as it is (not broadcast per image)
            shared_sky = not in_batched[3]
            per_image = _PerImage(poses, background, geom_rgb, sky_frame, None if shared_sky else sky_texture)
            flags = _PerImage._make((*in_batched[:3], in_batched[4], None if shared_sky else True))  # batched?
            args = jax.tree.map(lambda x, b: x if b else jnp.broadcast_to(x, (axis_size,) + x.shape), per_image, flags)

            def one_chunk(a: _PerImage):
                sky = sky_texture if shared_sky else a.sky_texture
                return self._trace_and_shade(a.poses, a.background, a.geom_rgb, sky, a.sky_frame, colour, batched=True)

            chunk = self.config.batch_chunk
            assert chunk is not None  # CameraConfig sets it
            out = chunks.map_chunks(one_chunk, args, chunk, axis_size)
            return out, jax.tree.map(lambda _: True, out)

        self._programs[colour] = batched
        return batched

    def _trace_and_shade(
        self, poses: tracing.Poses, background, geom_rgb, sky_texture, sky_frame, colour: bool, batched: bool
    ):
        """One image, or (``batched``) a leading axis of images: ``(rgb (H, W, 3) or None,
        depth (H, W), geom id (H, W))``: :meth:`_trace`, then (``colour``) :meth:`_shade`. An
        image whose camera pose is not finite sees nothing (depth ``zfar``, id ``-1``, black),
        whatever the other images of its batch."""
        lift = jax.vmap if batched else (lambda f: f)
        traced = self._trace(poses, lift)
        if not colour:
            return None, traced.depth, traced.ids
        rgb = self._shade(poses, traced, background, geom_rgb, sky_texture, sky_frame, lift)
        return rgb, traced.depth, traced.ids

    def _trace(self, poses: tracing.Poses, lift) -> _Traced:
        """The geometry pass: culled tracing first; if any image of the batch has more (tile,
        geom) pairs than the budget, dense tracing. ``lift``: ``jax.vmap`` over a batch, or the
        identity for one image."""
        tracer = self.tracer
        geom_frames = lift(tracer.geom_frames)(poses)
        seen = jnp.all(jnp.isfinite(poses["cam_pos"]), axis=-1) & jnp.all(
            jnp.isfinite(poses["cam_mat"]), axis=(-2, -1)
        )  # () or (C,) per image
        any_seen = jnp.any(seen)
        shape = jnp.shape(poses["cam_pos"])[:-1] + (self.config.height, self.config.width)

        def nothing():
            # derived from an input, so it carries the same sharding type under shard_map
            zero = 0.0 * jnp.nan_to_num(poses["cam_pos"][..., 0])[..., None, None]
            return (
                jnp.broadcast_to(zero + self.scene.zfar, shape),
                jnp.broadcast_to(zero.astype(jnp.int32) + len(self.scene.geom_ids), shape),
            )

        def padded_of(trace):
            return lambda: lift(tracing.pad_by_one_pixel)(trace())

        # Each stage runs inside a ``lax.cond`` on ``any_seen`` (the other branch gives zeros):
        # its results are materialised once, where XLA would otherwise fuse the nearest-hit
        # selection, or the shading, into every consumer (and the interleaved (H, W, 3) output
        # per channel) and redo it many times. Computed inside the branch, a stage writes its
        # outputs directly (a cond passing through values computed outside copies them).
        def dense():
            # the nearest-hit keys materialised first (fused into the padded outputs, the
            # search over all geoms would run once per output element and per output)
            keys = _materialised(lambda: lift(tracer.dense_keys)(geom_frames), any_seen)
            return lift(tracing.pad_by_one_pixel)(lift(tracer.decode)(keys))

        if tracer.culled_groups:
            keys, overflow = lift(tracer.culled_keys)(geom_frames)
            depth_p, best_p = jax.lax.cond(
                jnp.any(overflow & seen) | ~any_seen,
                lambda: jax.lax.cond(any_seen, dense, padded_of(nothing)),
                padded_of(lambda: lift(tracer.decode_tiled)(keys)),
            )
        else:
            depth_p, best_p = jax.lax.cond(any_seen, dense, padded_of(nothing))
        # a non-finite image of a traced batch: nothing seen (its own trace, a search with NaN
        # or inf poses, is not relied on)
        seen_px = seen[..., None, None]
        depth = jnp.where(seen_px, depth_p[..., 1:-1, 1:-1], jnp.float32(self.scene.zfar))
        best = best_p[..., 1:-1, 1:-1].astype(jnp.int32)
        ids = jnp.where(seen_px, jnp.asarray(np.append(self.scene.geom_ids, -1).astype(np.int32))[best], -1)
        return _Traced(geom_frames, seen, seen_px, any_seen, (depth_p, best_p), depth, ids)

    def _shade(
        self, poses: tracing.Poses, traced: _Traced, background, geom_rgb, sky_texture, sky_frame, lift
    ) -> jax.Array:
        """The colour pass over :meth:`_trace`'s planes: ``(H, W, 3)`` (per image)."""
        shader = self.shader
        geom_frames, seen, seen_px, any_seen, padded, depth, _ = traced
        depth_p, best_p = padded
        # Neighbour lookups read slices of the padded planes (no concatenates, which XLA's
        # CPU loops do not vectorise). The light (normals, lights) and a skybox texture's
        # texels are materialised, then the colour and composition in planes (fused into the
        # interleaved output they would run per element, unvectorised).
        if self.config.shading == "flat":
            light = (jnp.ones_like(depth),)
        else:
            light = _materialised(lambda: lift(shader.incident_light)(poses, padded), any_seen)
        if background.size == 0 and sky_texture.size != 0:
            # a non-finite pose's directions would index outside the texture stack
            safe_mat = jnp.where(seen[..., None, None], poses["cam_mat"], 0.0)
            texels = _materialised(lambda: shader.skybox_texels(safe_mat, sky_texture, sky_frame), any_seen)
            background = tuple(sky_lib.unpack_rgb(texels))
        planes = _materialised(
            lambda: lift(shader.compose)(
                poses, lift(shader.surface_colour)(geom_frames, padded, geom_rgb), light, best_p, background
            ),
            any_seen,
        )
        return jnp.where(seen_px[..., None], jnp.stack(planes, axis=-1), 0.0)


def _materialised(fn, pred):
    """``fn()`` computed inside a ``lax.cond`` on ``pred`` (which should hold; otherwise
    zeros of the same shapes), so that its outputs are materialised."""
    shapes = jax.eval_shape(fn)

    def zeros():
        zero = jnp.where(pred, 0, 0)  # carries pred's sharding type under shard_map
        return jax.tree.map(lambda s: jnp.broadcast_to(zero.astype(s.dtype), s.shape), shapes)

    return jax.lax.cond(pred, fn, zeros)


class _PerImage(NamedTuple):
    """The renderer's inputs as its batching rule splits them into chunks of images, each
    with a leading batch axis (``sky_texture`` ``None``: one stack every image shares)."""

    poses: tracing.Poses
    background: jax.Array
    geom_rgb: jax.Array
    sky_frame: jax.Array
    sky_texture: jax.Array | None


def _sky_stack_and_row(sky_texture) -> tuple[jax.Array, jax.Array]:
    """``render``'s ``sky_texture`` as a stack of packed frames and the row shown: ``(N, S * S)``
    int32 and a ``()`` int32 row clamped to the stack (``(0, 1)`` and row 0 for no texture)."""
    sky_frame = None
    if isinstance(sky_texture, (tuple, list)):
        sky_texture, sky_frame = sky_texture
        if not (
            sky_texture.ndim == 2
            and sky_texture.dtype == jnp.int32
            and math.isqrt(sky_texture.shape[1]) ** 2 == sky_texture.shape[1] > 0
            and sky_texture.size < 2**31
        ):
            raise ValueError(
                "sky_texture (stack, row): the stack must be packed frames "
                "(N, S * S) int32 (fewer than 2**31 texels), got "
                f"{sky_texture.dtype} {sky_texture.shape}"
            )
        if jnp.shape(sky_frame) != ():
            raise ValueError(
                f"sky_texture (stack, row): the row must be a scalar int, got shape {jnp.shape(sky_frame)}"
            )
        # clamped: the texel gather trusts its indices (a row past the stack reads past it)
        sky_frame = jnp.clip(jnp.asarray(sky_frame, jnp.int32), 0, sky_texture.shape[0] - 1)
    elif sky_texture is None:
        sky_texture = jnp.zeros((0, 1), jnp.int32)
    elif (
        sky_texture.ndim == 3
        and sky_texture.shape[0] == sky_texture.shape[1]
        and sky_texture.shape[2] == 3
        and sky_texture.dtype == jnp.uint8
    ):
        sky_texture = sky_lib.pack_rgb(sky_texture)[None]
    elif (
        sky_texture.ndim == 1
        and sky_texture.dtype == jnp.int32
        and math.isqrt(sky_texture.shape[0]) ** 2 == sky_texture.shape[0] > 0
    ):
        sky_texture = sky_texture[None]
    else:
        raise ValueError(
            "sky_texture must be (S, S, 3) uint8 or packed (S * S,) int32 (or a "
            f"pair (stack (N, S * S), row)), got {sky_texture.dtype} {sky_texture.shape}"
        )
    if sky_frame is None:
        sky_frame = jnp.zeros((), jnp.int32)
    return sky_texture, sky_frame


def _check_projection(mj_model: mujoco.MjModel, camera_id: int, height: int, width: int) -> None:
    """Refuses model cameras this camera would draw differently from MuJoCo's renderer: it
    draws a perspective frustum from ``cam_fovy`` and the image's aspect ratio."""
    projection = int(mj_model.cam_projection[camera_id])
    if projection != int(mujoco.mjtProjection.mjPROJ_PERSPECTIVE):
        raise ValueError(
            f"camera_id={camera_id} has projection {mujoco.mjtProjection(projection).name}; "
            "only perspective cameras (mjPROJ_PERSPECTIVE) are supported"
        )
    sensor = np.asarray(mj_model.cam_sensorsize[camera_id], np.float64)
    if np.any(sensor > 0):  # intrinsics (focal, principal, sensorsize) set the frustum
        fx, fy, cx, cy = (float(v) for v in mj_model.cam_intrinsic[camera_id])
        if not (fx == fy and cx == 0 and cy == 0 and math.isclose(sensor[0] / sensor[1], width / height, rel_tol=1e-6)):
            raise ValueError(
                f"camera_id={camera_id} has intrinsics (sensorsize {tuple(sensor)}, focal {(fx, fy)}, "
                f"principal {(cx, cy)}): supported only with equal focal lengths, principal (0, 0) "
                f"and width / height equal to the sensor's {sensor[0] / sensor[1]:.6g}, got {width}x{height}"
            )
