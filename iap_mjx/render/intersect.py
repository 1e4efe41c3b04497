"""Closed-form ray/primitive intersections in the primitive's local frame.

Each function takes the ray origin ``o`` and direction ``d`` in the geom's local frame as
3-tuples of arrays (any broadcastable shapes; the origin is usually one point per image and the
direction one vector per pixel) and the geom's MuJoCo ``size`` (Python floats, or arrays that
broadcast), and returns ``t``: the smallest positive ray parameter of an entry hit, ``inf`` for
a miss (the hit point is ``o + t d``). Rays starting inside a solid do not see it (front faces
only, as a rasteriser with back-face culling).

Written for XLA's CPU fusion: every divide and square root feeds exactly one ``where``, and
every hit condition is a divide- and root-free test on cheap terms, so a whole geom (and the
running nearest-hit minimum over geoms) fuses into one loop with nothing materialised. The
price is a few duplicated roots (computed as distinct expressions so they are not merged).
"""

from __future__ import annotations

import jax.numpy as jnp

from iap_mjx.render import scene as scene_lib

Vec = tuple[jnp.ndarray, ...]  # (x, y, z)

_TINY = 1e-30
_INF = jnp.inf


def _entry_root(b, a, c):
    """The smaller root of ``a t^2 + 2 b t + c = 0`` (``a > 0``), ``inf`` unless it is real
    and positive. Positive smaller root <=> ``b < 0`` and ``c > 0`` (origin outside, moving
    toward the surface), so the test needs no root."""
    disc = b * b - a * c
    ok = (disc >= 0.0) & (b < 0.0) & (c > 0.0)
    return jnp.where(ok, (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / jnp.maximum(a, _TINY), _INF)


def plane(o: Vec, d: Vec, size) -> jnp.ndarray:
    """The local z = 0 plane seen from its front (+z) side, within ``|x| <= size[0]`` and
    ``|y| <= size[1]`` (a static size of 0 means unbounded), as ``mj_ray`` does."""
    ok = (d[2] < 0.0) & (o[2] > 0.0)
    # hit point times -d_z (> 0): o_xy * -d_z + o_z * d_xy
    for i in range(2):
        if not (isinstance(size[i], (int, float)) and size[i] <= 0):
            ok &= jnp.abs(o[2] * d[i] - o[i] * d[2]) <= -size[i] * d[2]
    return jnp.where(ok, o[2] / -jnp.minimum(d[2], -_TINY), _INF)


def sphere(o: Vec, d: Vec, size) -> jnp.ndarray:
    """A sphere of radius ``size[0]`` at the origin."""
    r = size[0]
    a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    b = d[0] * o[0] + d[1] * o[1] + d[2] * o[2]
    c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - r * r
    return _entry_root(b, a, c)


def ellipsoid(o: Vec, d: Vec, size) -> jnp.ndarray:
    """An axis-aligned ellipsoid with semi-axes ``size`` at the origin."""
    inv = tuple(1.0 / s for s in size)
    return sphere(tuple(o[i] * inv[i] for i in range(3)), tuple(d[i] * inv[i] for i in range(3)), (1.0, 0.0, 0.0))


def _side_wall(o: Vec, d: Vec, r, h) -> jnp.ndarray:
    """Entry through the wall of the cylinder of radius ``r`` around z within ``|z| <= h``."""
    a = d[0] * d[0] + d[1] * d[1]
    b = d[0] * o[0] + d[1] * o[1]
    c = o[0] * o[0] + o[1] * o[1] - r * r
    disc = b * b - a * c
    # z at the entry, times a: o_z a + (-b - sqrt(disc)) d_z; its own (unmerged) root.
    z_times_a = o[2] * a - (b + jnp.sqrt(jnp.maximum(disc, _TINY))) * d[2]
    ok = (disc >= 0.0) & (b < 0.0) & (c > 0.0) & (jnp.abs(z_times_a) <= h * a)
    return jnp.where(ok, (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / jnp.maximum(a, _TINY), _INF)


def capsule(o: Vec, d: Vec, size) -> jnp.ndarray:
    """A capsule of radius ``size[0]`` around the local z axis, half-length ``size[1]``: the
    union of the wall and two end spheres, so its entry is the nearest of their entries."""
    r, h = size[0], size[1]
    t = _side_wall(o, d, r, h)
    a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    b_xy = d[0] * o[0] + d[1] * o[1]
    c_xy = o[0] * o[0] + o[1] * o[1] - r * r
    for end in (h, -h):
        oz = o[2] - end
        t = jnp.minimum(t, _entry_root(b_xy + d[2] * oz, a, c_xy + oz * oz))
    return t


def cylinder(o: Vec, d: Vec, size) -> jnp.ndarray:
    """A solid cylinder of radius ``size[0]`` around the local z axis, half-length ``size[1]``:
    the wall, or the flat end facing the ray origin."""
    r, h = size[0], size[1]
    t = _side_wall(o, d, r, h)
    cap = jnp.where(o[2] > 0.0, h, -h)
    rise = cap - o[2]  # t * d_z at the cap plane
    # hit point times d_z: o_xy d_z + rise d_xy, inside the disc of radius r |d_z|
    hx = o[0] * d[2] + rise * d[0]
    hy = o[1] * d[2] + rise * d[1]
    ok = (jnp.abs(o[2]) > h) & (rise * d[2] > 0.0) & (hx * hx + hy * hy <= r * r * d[2] * d[2])
    safe_dz = jnp.where(jnp.abs(d[2]) > _TINY, d[2], _TINY)
    return jnp.minimum(t, jnp.where(ok, rise / safe_dz, _INF))


def box(o: Vec, d: Vec, size) -> jnp.ndarray:
    """An axis-aligned box with half-sizes ``size``: the nearest hit among the (at most
    three) faces that face the ray origin."""
    t: jnp.ndarray | None = None
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        face = jnp.where(o[i] > 0.0, size[i], -size[i])
        rise = face - o[i]  # t * d_i at the face plane
        abs_di = jnp.abs(d[i])
        ok = (jnp.abs(o[i]) > size[i]) & (rise * d[i] > 0.0)
        ok &= jnp.abs(o[j] * d[i] + rise * d[j]) <= size[j] * abs_di
        ok &= jnp.abs(o[k] * d[i] + rise * d[k]) <= size[k] * abs_di
        safe_di = jnp.where(abs_di > _TINY, d[i], _TINY)
        t_face = jnp.where(ok, rise / safe_di, _INF)
        t = t_face if t is None else jnp.minimum(t, t_face)
    assert t is not None  # three faces
    return t


BY_TYPE = {
    scene_lib.PLANE: plane,
    scene_lib.SPHERE: sphere,
    scene_lib.CAPSULE: capsule,
    scene_lib.ELLIPSOID: ellipsoid,
    scene_lib.CYLINDER: cylinder,
    scene_lib.BOX: box,
}
"""mjtGeom code -> intersection function."""
