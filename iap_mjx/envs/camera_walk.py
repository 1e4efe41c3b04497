"""Camera-pose perturbations of the Distracting Control Suite, in JAX.

The reference is google-research ``distracting_control/camera.py``; this module computes
the same quantities (``tests/test_distraction_reference.py`` holds them against that code's own
functions). Per episode, the camera's offset ``p`` (a fixed camera's world position, a
``trackcom`` camera's position relative to body 1's subtree centre of mass) is written in
spherical coordinates ``(r, h, v)``: ``r = |p|``, azimuth ``h = atan2(p_y, p_x)``, polar
``v = atan2(|p_xy|, p_z)``. Its box: ``h`` and ``v`` within ``start +- pi b / 2``, roll
within ``+- pi b / 2``, ``r`` within ``[r0 (1 - b/2), r0 (1 + 3b/2)]``; with the
upper-quadrant limit (every domain but reacher) also ``v`` in ``[0, pi/2]`` and ``h`` in
``[-pi, 0]``. A reset draws ``(r, h, v, roll)`` uniformly in the box and a velocity (a
random direction times ``U(0, max_vel)``, a roll velocity ``U(-max_roll_vel,
max_roll_vel)``); then every control step (and once at reset) :func:`walk` moves it.
:func:`pose` turns the state into ``cam_xpos``/``cam_xmat``.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from flax import struct


class CameraWalk(struct.PyTreeNode):
    """One episode's camera perturbation (add a leading axis under ``vmap``).

    Attributes:
      sphere: ``(3,)`` the current ``(r, h, v)`` of the offset.
      roll: ``()`` radians about the optical axis.
      velocity: ``(3,)`` Cartesian velocity of the offset per control step.
      roll_velocity: ``()``.
      low, high: ``(3,)`` the box of ``(r, h, v)``.
      velocity_scale: ``()`` ``r0 / 4`` (the walk's steps scale with the camera's distance).
      lookat: ``(3,)`` a fixed camera's look-at point, from the reset state.
    """

    sphere: jax.Array
    roll: jax.Array
    velocity: jax.Array
    roll_velocity: jax.Array
    low: jax.Array
    high: jax.Array
    velocity_scale: jax.Array
    lookat: jax.Array


@dataclasses.dataclass(frozen=True)
class WalkSettings:
    """The scale-dependent constants (``distracting_control/suite_utils.get_camera_kwargs``).

    ``delta`` bounds the angles (``h``, ``v`` and roll: ``pi b / 2``); ``zoom_in``,
    ``zoom_out`` the radius (``b / 2``, ``3 b / 2``); ``vel_std``, ``max_vel``, ``roll_std``,
    ``max_roll_vel`` the walk (``0.1 b``, ``0.4 b``, ``pi b / 300``, ``pi b / 50`` if dynamic,
    else 0).
    """

    delta: float
    zoom_in: float
    zoom_out: float
    vel_std: float
    max_vel: float
    roll_std: float
    max_roll_vel: float
    upper_quadrant: bool

    @classmethod
    def make(cls, scale: float, dynamic: bool, upper_quadrant: bool) -> WalkSettings:
        on = 1.0 if dynamic else 0.0
        return cls(
            delta=math.pi / 2 * scale,
            zoom_in=0.5 * scale,
            zoom_out=1.5 * scale,
            vel_std=0.1 * scale * on,
            max_vel=0.4 * scale * on,
            roll_std=math.pi / 300 * scale * on,
            max_roll_vel=math.pi / 50 * scale * on,
            upper_quadrant=upper_quadrant,
        )


# ---- geometry -----------------------------------------------------------------------------


def to_sphere(p: jax.Array) -> jax.Array:
    """``(3,)`` Cartesian -> ``(r, h, v)``: radius, azimuth from +x, polar angle from +z."""
    return jnp.stack([jnp.linalg.norm(p), jnp.arctan2(p[1], p[0]), jnp.arctan2(jnp.linalg.norm(p[:2]), p[2])])


def to_cartesian(s: jax.Array) -> jax.Array:
    """``(r, h, v)`` -> ``(3,)`` Cartesian (the inverse of :func:`to_sphere`)."""
    r, h, v = s[0], s[1], s[2]
    return jnp.stack([r * jnp.sin(v) * jnp.cos(h), r * jnp.sin(v) * jnp.sin(h), r * jnp.cos(v)])


def _rx(a):
    c, s = jnp.cos(a), jnp.sin(a)
    one, zero = jnp.ones_like(a), jnp.zeros_like(a)
    return jnp.stack([jnp.stack([one, zero, zero]), jnp.stack([zero, c, -s]), jnp.stack([zero, s, c])])


def rz(a: jax.Array) -> jax.Array:
    """``(3, 3)`` rotation by ``a`` about z."""
    c, s = jnp.cos(a), jnp.sin(a)
    one, zero = jnp.ones_like(a), jnp.zeros_like(a)
    return jnp.stack([jnp.stack([c, -s, zero]), jnp.stack([s, c, zero]), jnp.stack([zero, zero, one])])


def look_at_upright(target: jax.Array, position: jax.Array) -> jax.Array:
    """``(3, 3)`` camera frame at ``position`` looking at ``target`` without roll: yaw
    ``atan2(d_x, d_y)`` and pitch ``atan2(d_z, |d_xy|) + pi/2`` of the unit direction ``d``,
    ``Rz(-yaw) @ Rx(pitch)`` (the reference's ``eul2mat([pitch, 0, -yaw])``; the camera
    looks along its -z)."""
    d = target - position
    d = d / jnp.linalg.norm(d)
    yaw = jnp.arctan2(d[0], d[1])
    pitch = jnp.arctan2(d[2], jnp.linalg.norm(d[:2])) + jnp.pi / 2
    return rz(-yaw) @ _rx(pitch)


def look_at_rotation(target: jax.Array, position: jax.Array) -> jax.Array:
    """``(3, 3)`` the rotation about ``(0, 0, -1) x d`` taking the camera's view axis
    ``(0, 0, -1)`` to the unit direction ``d`` (Rodrigues' formula), for cameras that look
    straight down (reacher), where :func:`look_at_upright` flips. As the reference, the axis
    is divided by ``|axis| + 1e-4``."""
    d = target - position
    d = d / jnp.linalg.norm(d)
    axis = jnp.cross(jnp.array([0.0, 0.0, -1.0], d.dtype), d)
    sin = jnp.linalg.norm(axis)
    cos = -d[2]
    a = axis / (sin + 1e-4)
    cross = jnp.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return cos * jnp.eye(3, dtype=d.dtype) + sin * cross + (1.0 - cos) * jnp.outer(a, a)


def lookat_point(cam_pos: jax.Array, cam_mat: jax.Array, com: jax.Array) -> jax.Array:
    """The point on the camera's optical axis as far away as ``com`` (body 1's subtree
    centre of mass): ``cam_pos + cam_mat @ (0, 0, -|cam_pos - com|)``."""
    return cam_pos - cam_mat[:, 2] * jnp.linalg.norm(cam_pos - com)


# ---- the walk -----------------------------------------------------------------------------


def start(
    key: jax.Array, settings: WalkSettings, cam_pos: jax.Array, cam_mat: jax.Array, com: jax.Array, tracking: bool
) -> CameraWalk:
    """A reset's draw (the reference's ``setup_camera``), before the first :func:`walk`.

    ``cam_pos`` ``(3,)``, ``cam_mat`` ``(3, 3)``: the unperturbed camera of the reset state;
    ``com``: body 1's subtree centre of mass; ``tracking``: a ``trackcom`` camera (else fixed).
    """
    offset = cam_pos - com if tracking else cam_pos
    r0, h0, v0 = to_sphere(offset)
    d = settings.delta
    low = jnp.stack([jnp.maximum(r0 * (1.0 - settings.zoom_in), 0.0), h0 - d, v0 - d])
    high = jnp.stack([r0 * (1.0 + settings.zoom_out), h0 + d, v0 + d])
    if settings.upper_quadrant:
        low = low.at[1].set(jnp.maximum(low[1], -jnp.pi)).at[2].set(jnp.maximum(low[2], 0.0))
        high = high.at[1].set(jnp.minimum(high[1], 0.0)).at[2].set(jnp.minimum(high[2], jnp.pi / 2))
    k_sphere, k_roll, k_dir, k_speed, k_roll_vel = jax.random.split(key, 5)
    sphere = jax.random.uniform(k_sphere, (3,), minval=low, maxval=high)
    roll = jax.random.uniform(k_roll, (), minval=-d, maxval=d)
    direction = jax.random.normal(k_dir, (3,))
    direction = direction / jnp.linalg.norm(direction)
    velocity = direction * jax.random.uniform(k_speed, (), maxval=settings.max_vel)
    roll_velocity = jax.random.uniform(k_roll_vel, (), minval=-settings.max_roll_vel, maxval=settings.max_roll_vel)
    return CameraWalk(
        sphere=sphere,
        roll=roll,
        velocity=velocity,
        roll_velocity=roll_velocity,
        low=low,
        high=high,
        velocity_scale=r0 / 4.0,
        lookat=lookat_point(cam_pos, cam_mat, com),
    )


def walk(state: CameraWalk, settings: WalkSettings, noise: jax.Array, roll_noise: jax.Array) -> CameraWalk:
    """One control step (the reference's ``_apply`` before the pose): the velocity takes a
    Gaussian step (``noise`` ``(3,)`` and ``roll_noise`` ``()`` standard normal), is capped
    (norm ``max_vel * r0/4``, roll ``+- max_roll_vel``), moves the offset in Cartesian space,
    and the result is clamped into the box in spherical coordinates; the velocity becomes
    the move actually made. Static settings leave the state where it is (after the first
    walk from the reset draw, which already clamps it)."""
    scale = state.velocity_scale
    velocity = state.velocity + noise * settings.vel_std * scale
    cap = settings.max_vel * scale
    norm = jnp.linalg.norm(velocity)
    velocity = jnp.where(norm > cap, velocity * (cap / jnp.maximum(norm, 1e-30)), velocity)
    roll_velocity = jnp.clip(
        state.roll_velocity + roll_noise * settings.roll_std, -settings.max_roll_vel, settings.max_roll_vel
    )
    position = to_cartesian(state.sphere)
    sphere = jnp.clip(to_sphere(position + velocity), state.low, state.high)
    roll = jnp.clip(state.roll + roll_velocity, -settings.delta, settings.delta)
    return state.replace(
        sphere=sphere, velocity=to_cartesian(sphere) - position, roll=roll, roll_velocity=roll - state.roll
    )


def pose(
    state: CameraWalk, settings: WalkSettings, cam_pos: jax.Array, cam_mat: jax.Array, com: jax.Array, tracking: bool
) -> tuple[jax.Array, jax.Array]:
    """The perturbed ``cam_xpos`` ``(3,)`` and ``cam_xmat`` ``(3, 3)`` for the current state
    (``cam_pos``, ``cam_mat``: the unperturbed camera now; ``com``: body 1's subtree centre
    of mass now). A fixed camera looks at its reset-time look-at point; a ``trackcom``
    camera's offset is added to ``com`` and it looks at the unperturbed camera's current
    look-at point. Then the roll about the optical axis: ``cam_xmat = R @ Rz(roll)``."""
    position = to_cartesian(state.sphere)
    if tracking:
        position = position + com
        target = lookat_point(cam_pos, cam_mat, com)
    else:
        target = state.lookat
    look = look_at_upright if settings.upper_quadrant else look_at_rotation
    return position, look(target, position) @ rz(state.roll)
