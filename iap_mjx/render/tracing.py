"""The camera's geometry pass: which geom each pixel's ray hits first, and how far away.

- Geometry moves into the camera frame once per image (:meth:`Tracer.geom_frames`): pixel
  ``(x, y)``'s ray is ``t * (x, y, -1)``, so the ray parameter ``t`` *is* the depth along the
  optical axis, and each geom's local ray direction is an affine function of ``(x, y)``.
  Intersections are closed forms per primitive (``intersect.py``), unrolled over the geoms
  (types and sizes are static).
- The nearest hit is one ``min`` over int32 keys that pack the depth and the geom index
  (:meth:`Tracer.key`): no argmin, no per-geom payloads.
- Types with many geoms (cheetah's capsules) are culled per screen tile: only the (tile, geom)
  pairs where the geom's projected bounds reach the tile are traced (:meth:`Tracer.culled_keys`),
  from a fixed-size list (``CameraConfig.cull_pairs_per_tile``, :func:`first_pairs`); a batch
  chunk with more pairs than that is traced densely instead (:meth:`Tracer.dense_keys`, chosen
  in ``camera.py``), so the result never depends on the culling.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NotRequired, TypedDict

import jax
import jax.numpy as jnp
import numpy as np

from iap_mjx.chunks import ceil_div
from iap_mjx.render import intersect
from iap_mjx.render import scene as scene_lib

if TYPE_CHECKING:  # camera.py imports this module
    from iap_mjx.render.camera import CameraConfig


class Poses(TypedDict):
    """The few per-state arrays the renderer reads: what ``Camera.poses`` takes from an
    ``mjx.Data`` (defined here, where the geometry pass first reads them, so that ``camera.py``
    and ``shading.py`` import it without a cycle). Shapes are one state's; under ``vmap`` each
    array has the batch's leading axes too (a recorded episode's ``(T, ...)``).

    ``G`` is the number of geoms drawn (``Scene.geom_ids``), ``L`` the number of model lights
    (``Scene.light_mode``, possibly 0); every array is float32.

    Keys:
      cam_pos: ``(3,)`` the camera's position in the world frame (``data.cam_xpos``).
      cam_mat: ``(3, 3)`` the camera's orientation, its axes as columns in world coordinates
        (``data.cam_xmat``).
      geom_pos: ``(G, 3)`` the drawn geoms' positions (``data.geom_xpos``).
      geom_mat: ``(G, 3, 3)`` the drawn geoms' orientations (``data.geom_xmat``).
      light_body_pos: ``(L, 3)`` the position of each light's body (``data.xpos``).
      light_body_mat: ``(L, 3, 3)`` the orientation of each light's body (``data.xmat``).
      light_body_com: ``(L, 3)`` the centre of mass of each light's body's subtree
        (``data.subtree_com``).
      light_target_pos: ``(L, 3)`` the position of each light's target body
        (``Scene.light_targetbodyid``; body 0 for lights without one); present only when
        ``Scene.has_aimed_lights``.
      light_target_com: ``(L, 3)`` the centre of mass of each target body's subtree; present
        only when ``Scene.has_aimed_lights``.
    """

    cam_pos: jax.Array
    cam_mat: jax.Array
    geom_pos: jax.Array
    geom_mat: jax.Array
    light_body_pos: jax.Array
    light_body_mat: jax.Array
    light_body_com: jax.Array
    light_target_pos: NotRequired[jax.Array]
    light_target_com: NotRequired[jax.Array]


class GeomFrames(TypedDict):
    """Per-geom constants of one image (:meth:`Tracer.geom_frames`), in the camera frame and
    the geoms' local frames; ``G`` geoms drawn, every array float32 (a leading batch axis
    under ``vmap``).

    Keys:
      r_cam: ``(G, 3, 3)`` each geom's axes in camera coordinates (``cam_mat^T geom_mat``):
        its rows are the camera's axes in the geom's frame.
      origin: ``(G, 3)`` the camera's position in each geom's frame.
      centre: ``(G, 3)`` each geom's centre in the camera frame.
    """

    r_cam: jax.Array
    origin: jax.Array
    centre: jax.Array


class Tracer:
    """The static ray layout of one camera and the traces over it.

    Built once from the scene, the camera config and the vertical field of view; its methods
    are pure functions of one image's poses (``vmap`` them for a batch).

    Attributes:
      x: ``(1, W)`` float32 image x coordinate of each column's pixel centre (the ray
        direction's x, at z = -1).
      y: ``(H, 1)`` float32 image y coordinate of each row's pixel centre (row 0 on top).
      pixel_pitch: ``(x, y)`` the pixel's size in image coordinates.
      tile_grid: ``(ny, nx, th, tw)``: tiles down and across, and a tile's height and width in
        pixels (the image padded to whole tiles is ``(ny * th, nx * tw)``).
      tile_x, tile_y: ``(ny * nx, th * tw)`` float32 image coordinates of each tile's pixels.
      grid_x, grid_y: ``(1, nx * tw)`` and ``(ny * th, 1)`` image coordinates of the padded
        image's columns and rows.
      tile_bounds: ``(ny * nx, 4)`` each tile's ``x_min, x_max, y_min, y_max``.
      pair_budget: (tile, geom) pairs traced per culled type group.
      culled_groups: ``((geom type, geom indices), ...)`` the type groups traced per tile.
      dense_geoms: indices of the geoms traced against every pixel.
    """

    def __init__(self, scene: scene_lib.Scene, config: CameraConfig, fovy: float):
        """``fovy``: vertical field of view in degrees."""
        self.scene = scene
        height, width = config.height, config.width
        self.height, self.width = height, width
        half_h = np.tan(np.deg2rad(fovy) / 2.0)
        half_w = half_h * width / height
        self.pixel_pitch = (float(2.0 * half_w / width), float(2.0 * half_h / height))
        self._lay_out_tiles(config.tile, half_w, half_h)
        # the image's own pixels of the grid: (1, W) and (H, 1) views whose new axis has stride
        # 0, which JAX embeds as a vector and a broadcast (a copied array: a full constant)
        self.x, self.y = self.grid_x[0, :width][None, :], self.grid_y[:height, 0][:, None]
        n_tiles = self.tile_x.shape[0]
        self.pair_budget = int(np.ceil(config.cull_pairs_per_tile * n_tiles))
        groups: dict[int, list[int]] = {}
        for k, gtype in enumerate(scene.geom_type):
            groups.setdefault(int(gtype), []).append(k)
        self.culled_groups = tuple(
            (gtype, tuple(members))
            for gtype, members in sorted(groups.items())
            if gtype != scene_lib.PLANE and self.pair_budget > 0 and len(members) >= 3
        )
        culled = {k for _, members in self.culled_groups for k in members}
        self.dense_geoms = tuple(k for k in range(len(scene.geom_ids)) if k not in culled)

    def _lay_out_tiles(self, tile: int, half_w: float, half_h: float) -> None:
        """Static tile layout: pixel image coordinates per tile and each tile's bounds."""
        height, width = self.height, self.width
        th, tw = min(tile, height), min(tile, width)
        ny, nx = ceil_div(height, th), ceil_div(width, tw)
        cols = ((np.arange(nx * tw) + 0.5) / width * 2.0 - 1.0) * half_w
        rows = (1.0 - (np.arange(ny * th) + 0.5) / height * 2.0) * half_h
        x = np.broadcast_to(cols[None, :], (ny * th, nx * tw)).reshape(ny, th, nx, tw)
        y = np.broadcast_to(rows[:, None], (ny * th, nx * tw)).reshape(ny, th, nx, tw)
        self.tile_grid = (ny, nx, th, tw)
        self.tile_x = np.moveaxis(x, 2, 1).reshape(ny * nx, th * tw).astype(np.float32)
        self.tile_y = np.moveaxis(y, 2, 1).reshape(ny * nx, th * tw).astype(np.float32)
        self.grid_x = cols[None, :].astype(np.float32)  # (1, nx * tw)
        self.grid_y = rows[:, None].astype(np.float32)  # (ny * th, 1)
        self.tile_bounds = np.stack(
            [self.tile_x.min(1), self.tile_x.max(1), self.tile_y.min(1), self.tile_y.max(1)], axis=1
        )

    def geom_frames(self, poses: Poses) -> GeomFrames:
        """Per-geom constants of one image in camera and local frames (:class:`GeomFrames`):
        ``r_cam`` ``(G, 3, 3)`` (geom axes in camera coordinates), ``origin`` ``(G, 3)`` (the
        camera in each geom's frame) and ``centre`` ``(G, 3)`` (each geom's centre in the
        camera frame), from one image's :class:`Poses`."""
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

    def dense_keys(self, frames: GeomFrames) -> jax.Array:
        """Every geom against every pixel: the nearest-hit keys (:meth:`key`) ``(H, W)`` int32
        of one image's :meth:`geom_frames`."""
        x, y = jnp.asarray(self.x), jnp.asarray(self.y)
        r_cam, origin = frames["r_cam"], frames["origin"]
        shape = (self.height, self.width)
        keys = [self.far_key(shape)] + [
            jnp.broadcast_to(self.key(self.hit_depth(k, r_cam, origin, x, y), k), shape)
            for k in range(len(self.scene.geom_ids))
        ]
        return jnp.min(jnp.stack(keys), axis=0)

    def culled_keys(self, frames: GeomFrames) -> tuple[jax.Array, jax.Array]:
        """Planes and small type groups against every pixel; each culled type group only
        against the tiles its geoms' projected bounds reach: the (tile, geom) pairs are listed
        (at most ``self.pair_budget`` per group), each pair traces its tile's pixels, and a
        scatter-min of the tile windows merges them. Takes one image's :meth:`geom_frames`;
        returns the nearest-hit keys (:meth:`key`) ``(ny * th, nx * tw)`` int32 (the image
        padded to whole tiles) and ``overflow`` ``()`` bool, true if a group had more pairs
        than the budget (the result is then incomplete and the caller falls back to
        :meth:`dense_keys`)."""
        sc = self.scene
        ny, nx, th, tw = self.tile_grid
        gx, gy = jnp.asarray(self.grid_x), jnp.asarray(self.grid_y)
        tx, ty = jnp.asarray(self.tile_x), jnp.asarray(self.tile_y)
        r_cam, origin = frames["r_cam"], frames["origin"]
        shape = (ny * th, nx * tw)
        keys = jnp.min(
            jnp.stack(
                [self.far_key(shape)]
                + [
                    jnp.broadcast_to(self.key(self.hit_depth(k, r_cam, origin, gx, gy), k), shape)
                    for k in self.dense_geoms
                ]
            ),
            axis=0,
        )
        overflow = jnp.zeros((), bool)
        budget = self.pair_budget
        windows = jax.lax.ScatterDimensionNumbers(
            update_window_dims=(1, 2), inserted_window_dims=(), scatter_dims_to_operand_dims=(0, 1)
        )
        for gtype, members in self.culled_groups:
            members_arr = jnp.asarray(members, jnp.int32)
            overlap = self.tile_overlap(frames, members).reshape(-1)  # tile-major pairs
            overflow |= jnp.sum(overlap) > budget
            pair, valid = first_pairs(overlap, budget)
            tile, local = pair // len(members), pair % len(members)
            # one gather per pair, 15 columns: 0-2, 3-5 and 6-8 the coefficients of the pixel's
            # x, y and 1 in the ray's direction in the geom's frame (x r_0 + y r_1 - r_2), 9-11
            # the camera's origin in that frame, 12-14 the geom's size
            params = jnp.concatenate(
                [
                    r_cam[members_arr, 0, :],
                    r_cam[members_arr, 1, :],
                    -r_cam[members_arr, 2, :],
                    origin[members_arr],
                    jnp.asarray(sc.geom_size[list(members)]),
                ],
                axis=1,
            )[local]
            col = [params[:, i : i + 1] for i in range(15)]
            px, py = tx[tile], ty[tile]
            d = tuple(px * col[i] + py * col[3 + i] + col[6 + i] for i in range(3))
            t = intersect.BY_TYPE[gtype](tuple(col[9:12]), d, tuple(col[12:15]))
            pair_keys = jnp.where(valid[:, None], self.key(t, members_arr[local][:, None]), jnp.iinfo(jnp.int32).max)
            corner = jnp.stack([tile // nx * th, tile % nx * tw], axis=1)  # (budget, 2)
            keys = jax.lax.scatter_min(
                keys,
                corner,
                pair_keys.reshape(budget, th, tw),
                windows,
                indices_are_sorted=True,
                mode=jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS,
            )
        return keys, overflow

    def tile_overlap(self, frames: GeomFrames, members: tuple[int, ...]) -> jax.Array:
        """``(tiles, len(members))`` bool: may the geom cover a pixel centre of the tile?
        ``frames``: one image's :meth:`geom_frames`; ``members``: geom indices (into
        ``scene.geom_ids``) of one type group, ``tiles`` is ``ny * nx``.
        Each geom is bounded by one sphere, or (capsule, cylinder) by the convex hull of its
        two end spheres (the capsule, which holds the cylinder); each sphere by a conservative
        box in image coordinates ``x / -z, y / -z``, and the hull by the box around its
        spheres' boxes (in front of the camera, a convex hull projects into the hull of the
        projections); a geom reaching the camera plane covers everything."""
        sc = self.scene
        idx = jnp.asarray(members)
        centre = frames["centre"][idx]
        axis = frames["r_cam"][idx, :, 2]
        radii, halves = [], []
        for k in members:
            size = sc.geom_size[k]
            gtype = int(sc.geom_type[k])
            if gtype in (scene_lib.CAPSULE, scene_lib.CYLINDER):
                radii.append(size[0])
                halves.append(size[1])
            elif gtype == scene_lib.BOX:
                radii.append(float(np.linalg.norm(size)))
                halves.append(0.0)
            else:
                radii.append(float(np.max(size)) if gtype == scene_lib.ELLIPSOID else size[0])
                halves.append(0.0)
        radius = jnp.asarray(np.asarray(radii, np.float32))[:, None]
        half = jnp.asarray(np.asarray(halves, np.float32))[:, None, None]
        ends = centre[:, None, :] + jnp.asarray([1.0, -1.0])[None, :, None] * half * axis[:, None, :]
        near = -ends[..., 2] - radius
        far = -ends[..., 2] + radius
        # a sphere within 1e-6 m of the camera plane counts as reaching it (its projected
        # box would be unbounded); boxes grow by 1e-4 in image coordinates (about 1e-4 rad,
        # far above the float32 rounding of the bounds) so rounding never culls a hit
        crosses = jnp.any(near <= 1e-6, axis=1) & jnp.any(far > 0.0, axis=1)
        behind = jnp.all(far <= 0.0, axis=1)
        safe_near = jnp.maximum(near, 1e-6)

        def extent(c: jax.Array) -> tuple[jax.Array, jax.Array]:
            lo = c - radius
            hi = c + radius
            lo = jnp.where(lo >= 0, lo / far, lo / safe_near)
            hi = jnp.where(hi >= 0, hi / safe_near, hi / far)
            return jnp.min(lo, axis=1) - 1e-4, jnp.max(hi, axis=1) + 1e-4

        x_lo, x_hi = extent(ends[..., 0])
        y_lo, y_hi = extent(ends[..., 1])
        t = self.tile_bounds
        overlap = (
            (x_lo[None] <= t[:, 1:2])
            & (x_hi[None] >= t[:, 0:1])
            & (y_lo[None] <= t[:, 3:4])
            & (y_hi[None] >= t[:, 2:3])
        )
        return (overlap | crosses[None]) & ~behind[None]

    def hit_depth(self, k: int, r_cam: jax.Array, origin: jax.Array, x: jax.Array, y: jax.Array) -> jax.Array:
        """Ray parameter (= depth) of geom ``k`` (a static index into ``scene.geom_ids``) for
        pixels at image coordinates ``x, y`` (its type and size unrolled as constants): float32
        in the shape ``x`` and ``y`` broadcast to (``(1, W)`` and ``(H, 1)`` give ``(H, W)``),
        ``inf`` where the ray misses. ``r_cam`` ``(G, 3, 3)`` and ``origin`` ``(G, 3)``:
        :class:`GeomFrames`'s."""
        sc = self.scene
        size = tuple(float(s) for s in sc.geom_size[k])
        o = (origin[k, 0], origin[k, 1], origin[k, 2])
        d = tuple(x * r_cam[k, 0, i] + (y * r_cam[k, 1, i] - r_cam[k, 2, i]) for i in range(3))
        return intersect.BY_TYPE[int(sc.geom_type[k])](o, d, size)

    @property
    def index_mask(self) -> int:
        """The low bits of a key that hold the geom index."""
        return (1 << max(1, len(self.scene.geom_ids).bit_length())) - 1

    def key(self, t: jax.Array, k: int | jax.Array) -> jax.Array:
        """int32 key of a hit at ray parameter ``t`` (float32, any shape) on geom index ``k``
        (a static int, or int32 broadcasting against ``t``), in their broadcast shape.

        A positive float's bits order like its value, so replacing the depth's low mantissa
        bits by the geom index gives keys whose minimum is the nearest hit *and* names its
        geom (the depth loses those bits: a relative error below ``2**(bits - 23)``, under
        1e-5 for up to 63 geoms). One ``min`` then replaces an argmin with payloads.
        """
        bits = jax.lax.bitcast_convert_type(jnp.maximum(t, 0.0), jnp.int32)
        return (bits & ~self.index_mask) | k

    def far_key(self, shape: tuple[int, int]) -> jax.Array:
        """Keys of 'nothing before the far plane' (index ``G``): int32 of shape ``shape``."""
        zfar_bits = int(np.float32(self.scene.zfar).view(np.int32))
        return jnp.full(shape, (zfar_bits & ~self.index_mask) | len(self.scene.geom_ids), jnp.int32)

    def decode(self, keys: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Keys (:meth:`key`, int32, any shape) -> depth, float32 (far plane where nothing is
        hit), and geom index, int32 (``G`` if none), both of the keys' shape."""
        n_geom = len(self.scene.geom_ids)
        index = keys & self.index_mask
        depth = jax.lax.bitcast_convert_type(keys & ~self.index_mask, jnp.float32)
        return jnp.where(index == n_geom, jnp.float32(self.scene.zfar), depth), index

    def decode_tiled(self, keys: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Keys ``(ny * th, nx * tw)`` int32 of the image padded to whole tiles
        (:meth:`culled_keys`) -> depth ``(H, W)`` float32 and geom index ``(H, W)`` int32
        (:meth:`decode`)."""
        return self.decode(keys[: self.height, : self.width])


def first_pairs(overlap: jax.Array, budget: int) -> tuple[jax.Array, jax.Array]:
    """The indices of the first ``budget`` true entries of ``overlap`` ``(P,)`` bool, in order,
    ``(budget,)`` int32, and which of those slots hold one (``(budget,)`` bool; empty slots
    hold ``P - 1``, so the list stays sorted, as the tile scatter promises XLA). Ranks come
    from a prefix sum done as two small triangular matmuls (exact for counts below 2**24),
    then one scatter: JAX lowers ``cumsum`` to a reduce-window as long as the list, and
    ``top_k`` is a sort; on a CPU both do more work than two small matmuls."""
    n = overlap.shape[0]
    row = next(r for r in (64, 32, 16, 8, 4, 2, 1) if n % r == 0)
    x = overlap.astype(jnp.float32).reshape(n // row, row)
    within = x @ jnp.asarray(np.triu(np.ones((row, row), np.float32)))  # inclusive, per row
    before = jnp.asarray(np.tril(np.ones((n // row,) * 2, np.float32), -1)) @ jnp.sum(x, axis=1)
    rank = (within + before[:, None]).reshape(n).astype(jnp.int32) - 1
    slot = jnp.where(overlap, rank, budget)  # past the end: dropped
    pair = jnp.full(budget, n - 1, jnp.int32).at[slot].set(jnp.arange(n, dtype=jnp.int32), mode="drop")
    return pair, jnp.arange(budget) < jnp.sum(overlap)


def pad_by_one_pixel(depth_and_best: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
    """Depth ``(H, W)`` float32 and geom index ``(H, W)`` int32 (:meth:`Tracer.decode`) with a
    one-pixel border (depth 0, geom -1: no neighbour), ``(H + 2, W + 2)``, both float32 (CPU
    loops that mix int32 tests into float math do not vectorise; geom indices are exact in
    float32). Shading reads a pixel's neighbours as slices of these padded planes."""
    depth, best = depth_and_best
    return jnp.pad(depth, 1), jnp.pad(best.astype(jnp.float32), 1, constant_values=-1.0)
