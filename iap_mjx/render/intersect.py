"""Closed-form ray/primitive intersections in the primitive's local frame.

Each function takes the ray origin ``o`` and direction ``d`` in the geom's local frame as
3-tuples of arrays (any broadcastable shapes; the origin is usually one point per image and the
direction one vector per pixel), the geom's MuJoCo size as Python floats (static), and returns
``(t, n)``: ``t`` the smallest positive ray parameter of an entry hit (``inf`` for a miss; the
hit point is ``o + t d``) and ``n`` the outward surface normal there, local frame, not
normalised. Rays starting inside a solid are not handled (a camera inside a geom sees nothing
of it), like front-face-only rendering.
"""

from __future__ import annotations

import jax.numpy as jnp

from iap_mjx.render import scene as scene_lib

Vec = tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]

_TINY = 1e-12


def _nearest_root(b: jnp.ndarray, a: jnp.ndarray, c: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Smaller root of ``a t^2 + 2 b t + c = 0`` and whether it is real and positive."""
    disc = b * b - a * c
    t = (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / jnp.maximum(a, _TINY)
    return t, (disc >= 0.0) & (t > 0.0)


def plane(o: Vec, d: Vec, size: tuple[float, float, float]) -> tuple[jnp.ndarray, Vec]:
    """The local z = 0 plane seen from its front (+z) side, within ``|x| <= size[0]`` and
    ``|y| <= size[1]`` (a size of 0 means unbounded), as ``mj_ray`` does."""
    t = -o[2] / jnp.minimum(d[2], -_TINY)
    ok = (d[2] < 0.0) & (o[2] > 0.0)
    if size[0] > 0:
        ok &= jnp.abs(o[0] + t * d[0]) <= size[0]
    if size[1] > 0:
        ok &= jnp.abs(o[1] + t * d[1]) <= size[1]
    zero = jnp.zeros_like(t)
    return jnp.where(ok, t, jnp.inf), (zero, zero, zero + 1.0)


def sphere(o: Vec, d: Vec, size: tuple[float, float, float]) -> tuple[jnp.ndarray, Vec]:
    """A sphere of radius ``size[0]`` at the origin."""
    r = size[0]
    a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    b = d[0] * o[0] + d[1] * o[1] + d[2] * o[2]
    c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - r * r
    t, ok = _nearest_root(b, a, c)
    t = jnp.where(ok, t, jnp.inf)
    return t, tuple(o[i] + t * d[i] for i in range(3))


def ellipsoid(o: Vec, d: Vec, size: tuple[float, float, float]) -> tuple[jnp.ndarray, Vec]:
    """An axis-aligned ellipsoid with semi-axes ``size`` at the origin."""
    inv = tuple(1.0 / s for s in size)
    os_ = tuple(o[i] * inv[i] for i in range(3))
    ds = tuple(d[i] * inv[i] for i in range(3))
    t, _ = sphere(os_, ds, (1.0, 0.0, 0.0))
    p = tuple(os_[i] + t * ds[i] for i in range(3))
    return t, tuple(p[i] * inv[i] for i in range(3))


def capsule(o: Vec, d: Vec, size: tuple[float, float, float]) -> tuple[jnp.ndarray, Vec]:
    """A capsule of radius ``size[0]`` around the local z axis, half-length ``size[1]``.

    The entry point lies on the side wall if the ray enters the infinite cylinder within
    ``|z| <= h``; otherwise it can only lie on the end sphere on that side.
    """
    r, h = size[0], size[1]
    a_xy = d[0] * d[0] + d[1] * d[1]
    b_xy = d[0] * o[0] + d[1] * o[1]
    c_xy = o[0] * o[0] + o[1] * o[1] - r * r
    t_side, ok_side = _nearest_root(b_xy, a_xy, c_xy)
    disc_ok = b_xy * b_xy - a_xy * c_xy >= 0.0
    z_side = jnp.where(a_xy > _TINY, o[2] + t_side * d[2], -d[2])
    on_side = ok_side & (jnp.abs(z_side) <= h)
    cap_z = jnp.where(z_side > 0.0, h, -h)
    oz = o[2] - cap_z
    a = a_xy + d[2] * d[2]
    b = b_xy + d[2] * oz
    c = o[0] * o[0] + o[1] * o[1] + oz * oz - r * r
    t_cap, ok_cap = _nearest_root(b, a, c)
    t = jnp.where(on_side, t_side, jnp.where(ok_cap & disc_ok, t_cap, jnp.inf))
    p = tuple(o[i] + t * d[i] for i in range(3))
    return t, (p[0], p[1], p[2] - jnp.clip(p[2], -h, h))


def cylinder(o: Vec, d: Vec, size: tuple[float, float, float]) -> tuple[jnp.ndarray, Vec]:
    """A solid cylinder of radius ``size[0]`` around the local z axis, half-length ``size[1]``:
    the side wall within ``|z| <= h`` or the flat end on the origin's side."""
    r, h = size[0], size[1]
    a_xy = d[0] * d[0] + d[1] * d[1]
    b_xy = d[0] * o[0] + d[1] * o[1]
    c_xy = o[0] * o[0] + o[1] * o[1] - r * r
    t_side, ok_side = _nearest_root(b_xy, a_xy, c_xy)
    on_side = ok_side & (jnp.abs(o[2] + t_side * d[2]) <= h)
    cap_z = jnp.where(o[2] > 0.0, h, -h)
    safe_dz = jnp.where(jnp.abs(d[2]) > _TINY, d[2], _TINY)
    t_cap = (cap_z - o[2]) / safe_dz
    x, y = o[0] + t_cap * d[0], o[1] + t_cap * d[1]
    on_cap = (t_cap > 0.0) & (x * x + y * y <= r * r) & (jnp.abs(o[2]) > h)
    t_side = jnp.where(on_side, t_side, jnp.inf)
    t_cap = jnp.where(on_cap, t_cap, jnp.inf)
    use_cap = t_cap < t_side
    t = jnp.minimum(t_side, t_cap)
    px, py = o[0] + t * d[0], o[1] + t * d[1]
    zero = jnp.zeros_like(t)
    n = (
        jnp.where(use_cap, zero, px),
        jnp.where(use_cap, zero, py),
        jnp.where(use_cap, jnp.sign(cap_z) + zero, zero),
    )
    return t, n


def box(o: Vec, d: Vec, size: tuple[float, float, float]) -> tuple[jnp.ndarray, Vec]:
    """An axis-aligned box with half-sizes ``size`` (slab method)."""
    t_near, t_far, near_axis = [], [], []
    for i in range(3):
        inv = 1.0 / jnp.where(jnp.abs(d[i]) > _TINY, d[i], _TINY)
        t1 = (-size[i] - o[i]) * inv
        t2 = (size[i] - o[i]) * inv
        t_near.append(jnp.minimum(t1, t2))
        t_far.append(jnp.maximum(t1, t2))
    enter = jnp.maximum(jnp.maximum(t_near[0], t_near[1]), t_near[2])
    leave = jnp.minimum(jnp.minimum(t_far[0], t_far[1]), t_far[2])
    ok = (enter <= leave) & (enter > 0.0)
    t = jnp.where(ok, enter, jnp.inf)
    zero = jnp.zeros_like(t)
    n = tuple(jnp.where(t_near[i] == enter, -jnp.sign(d[i]), zero) for i in range(3))
    return t, n


BY_TYPE = {
    scene_lib.PLANE: plane,
    scene_lib.SPHERE: sphere,
    scene_lib.CAPSULE: capsule,
    scene_lib.ELLIPSOID: ellipsoid,
    scene_lib.CYLINDER: cylinder,
    scene_lib.BOX: box,
}
"""mjtGeom code -> intersection function."""
