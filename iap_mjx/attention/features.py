"""Kernel feature maps: random projections, feature functions and their closed-form errors.

A feature map ``phi`` turns queries and keys of shape ``(..., d)`` into features of shape
``(..., M)`` such that ``phi(x, role="query") . phi(y, role="key")`` estimates a kernel
``K(x, y)`` (``docs/iap-math.md`` sections 3-5):

=============  ===================================================================  ==============
kind           estimates                                                            features ``M``
=============  ===================================================================  ==============
``"relu"``     the ReLU kernel ``(relu(x) + eps).(relu(y) + eps)`` (deterministic)  ``d``
``"exp"``      ``exp(x.y)``, FAVOR+ positive features                               ``m``
``"trig"``     ``exp(x.y)``, trigonometric features                                 ``2m``
``"hybrid"``   ``exp(x.y)``, hybrid features (eq. 7-9)                              ``3m(r+1)``
``"angular"``  ``1 - 2 theta / pi``, sign features                                  ``r``
=============  ===================================================================  ==============

The projection matrices are drawn once by :func:`draw_projections` and passed in, so the
feature functions are pure and the same draw can serve every image of a batch.

Numerics. Every feature is computed as ``exp(log_magnitude) * unit`` with the whole exponent
summed first (``omega.z - |z|^2/2`` for the positive blocks), so positive features never
overflow (that exponent is at most ``|omega|^2 / 2``). Trigonometric blocks carry
``exp(+|z|^2/2)``, whose products overflow float32 once ``|x|^2/2 + |y|^2/2 > 88``. With
``stabilize=True`` one shift per set of tokens (the largest log-magnitude over the set axis
``-2`` and all features) is subtracted, which multiplies every query feature by one positive
constant ``c_q`` and every key feature by one ``c_k``. Scores then come out multiplied by
``c_q c_k > 0``: their ranking, which is all that top-l selection uses, is unchanged (this is
not Performer's per-row shift, which only cancels under row normalisation).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
from flax import struct

from iap_mjx.checks import require_choice, require_int
from iap_mjx.chunks import ceil_div

KINDS = ("relu", "exp", "trig", "hybrid", "angular")
ROLES = ("query", "key")
MSE_KINDS = ("exp", "trig", "hybrid")
RELU_EPSILON = 1e-3


class Projections(struct.PyTreeNode):
    """Random projections for one feature map (``None`` where a kind needs none).

    Attributes:
      omega: ``(m, d)`` Gaussian directions for ``exp``/``trig``/``hybrid``.
      xi: ``(r, d)`` Gaussian directions for the sign features of ``hybrid``/``angular``.
    """

    omega: jax.Array | None = None
    xi: jax.Array | None = None


def check_kind(kind: str) -> None:
    """Raises ``ValueError`` naming the valid kinds if ``kind`` is not one of them."""
    require_choice("feature map kind", kind, KINDS)


def check_role(role: str) -> None:
    """Raises ``ValueError`` naming the valid roles if ``role`` is not one of them."""
    require_choice("role", role, ROLES)


def _check_count(name: str, value: int | None) -> int:
    require_int(name, value)
    assert value is not None  # require_int refuses None
    return value


def drawn(matrix: jax.Array | None, name: str, kind: str) -> jax.Array:
    """``matrix``, the projections' ``name`` that feature map ``kind`` needs, or a
    ``ValueError`` saying how to draw it."""
    if matrix is None:
        raise ValueError(
            f"projections lack the matrices that kind {kind!r} needs ({name} is None); "
            f"draw them with draw_projections(key, {kind!r}, ...)"
        )
    return matrix


def feature_count(kind: str, *, m: int | None = None, d: int | None = None, r: int | None = None) -> int:
    """The feature dimension ``M`` of ``kind`` (see the module table)."""
    check_kind(kind)
    if kind == "relu":
        return _check_count("d", d)
    if kind == "angular":
        return _check_count("r", r if r is not None else m)
    m = _check_count("m", m)
    if kind == "exp":
        return m
    if kind == "trig":
        return 2 * m
    return 3 * m * (_check_count("r", r) + 1)


def gaussian_directions(key: jax.Array, count: int, d: int, *, orthogonal: bool) -> jax.Array:
    """``(count, d)`` rows with ``N(0, I_d)`` marginals.

    ``orthogonal=False``: iid Gaussian rows. ``orthogonal=True``: Performer's block-orthogonal
    ensemble: rows come in blocks of ``d`` exactly orthogonal directions (Gram-Schmidt on a
    Gaussian ``d x d`` matrix, :func:`_orthonormal_rows`), each row rescaled to the norm of an
    independent Gaussian vector (chi distributed with ``d`` degrees of freedom), so each row is
    still marginally ``N(0, I_d)``.
    """
    if not orthogonal:
        return jax.random.normal(key, (count, d))
    n_blocks = ceil_div(count, d)
    block_key, norm_key = jax.random.split(key)
    blocks = jax.vmap(_orthonormal_rows)(jax.random.normal(block_key, (n_blocks, d, d)))
    rows = blocks.reshape(n_blocks * d, d)[:count]
    norms = jnp.linalg.norm(jax.random.normal(norm_key, (count, d)), axis=-1)
    return rows * norms[:, None]


def _orthonormal_rows(gaussian: jax.Array) -> jax.Array:
    """Gram-Schmidt on the rows of a Gaussian ``(d, d)`` matrix -> Haar-random orthonormal rows.

    Plain array ops rather than ``jnp.linalg.qr``: under a large ``vmap`` its LAPACK custom
    call can deadlock XLA's CPU runtime in jaxlib 0.10 (as MJX's batched Cholesky does:
    ``iap_mjx.envs.dmc.serial_lapack_batch``), and ``d`` is small here.
    """
    rows: list[jax.Array] = []
    for vector in gaussian:
        for previous in rows:
            vector = vector - jnp.dot(vector, previous) * previous
        rows.append(vector / jnp.linalg.norm(vector))
    return jnp.stack(rows)


def draw_projections(
    key: jax.Array, kind: str, *, m: int, d: int, r: int | None = None, orthogonal: bool = True
) -> Projections:
    """Draws the random matrices that ``kind`` needs.

    Args:
      key: PRNG key.
      kind: one of :data:`KINDS`.
      m: number of random features ``omega`` (``exp``/``trig``/``hybrid``); for ``angular``
        it is the number of sign features when ``r`` is not given.
      d: query/key dimension.
      r: number of sign features ``xi`` (``hybrid``: required; ``angular``: default ``m``).
      orthogonal: block-orthogonal rows (lower variance) or iid Gaussian rows.

    Returns:
      :class:`Projections` with ``omega`` ``(m, d)`` and/or ``xi`` ``(r, d)``.
    """
    check_kind(kind)
    _check_count("d", d)
    if kind == "relu":
        return Projections()
    omega_key, xi_key = jax.random.split(key)
    if kind == "angular":
        r = _check_count("r", r if r is not None else m)
        return Projections(xi=gaussian_directions(xi_key, r, d, orthogonal=orthogonal))
    m = _check_count("m", m)
    omega = gaussian_directions(omega_key, m, d, orthogonal=orthogonal)
    if kind == "hybrid":
        r = _check_count("r", r)
        return Projections(omega=omega, xi=gaussian_directions(xi_key, r, d, orthogonal=orthogonal))
    return Projections(omega=omega)


class FeatureFactors(struct.PyTreeNode):
    """The factors every softmax-estimating map is built from, for tokens ``(..., d)``.

    A feature is ``exp(log_magnitude - shift) * unit``; ``m`` features share one ``omega``.

    Attributes:
      trig_log: ``(..., 1)`` ``|z|^2 / 2``, log-magnitude of the trigonometric features.
      sin, cos: ``(..., m)`` ``sin(omega z)`` and ``cos(omega z)``.
      exp_log: ``(..., m)`` ``omega z - |z|^2 / 2``, log-magnitude of the positive features.
      signs: ``(..., r)`` ``sgn(xi z)`` in ``{-1, +1}``, or ``None`` without ``xi``.
    """

    trig_log: jax.Array
    sin: jax.Array
    cos: jax.Array
    exp_log: jax.Array
    signs: jax.Array | None


# pi split in three float32 parts (Cody-Waite): n * _PI_HI is exact for |n| < 2^16.
_PI_HI = 3.140625
_PI_MID = 9.67502593994140625e-4
_PI_LO = 1.509957990978376432e-7


def sincos(x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(sin(x), cos(x))`` with plain multiply-adds that XLA's CPU backend vectorises.

    Cody-Waite reduction to ``x = n pi + r``, ``|r| <= pi/2``; Taylor polynomials of ``sin r``
    (to ``r^11``) and ``cos r`` (to ``r^12``), then ``(-1)^n`` applied by flipping the sign bit
    (no quadrant selects). Within 2e-7 of the true values for ``|x| < 1e3``.
    """
    n = jnp.round(x * (1.0 / math.pi))
    r = ((x - n * _PI_HI) - n * _PI_MID) - n * _PI_LO
    z = r * r
    sin = r + r * z * (
        -1.6666666666e-1 + z * (8.3333333333e-3 + z * (-1.9841269841e-4 + z * (2.7557319223e-6 + z * -2.5052108385e-8)))
    )
    cos = 1.0 + z * (
        -0.5
        + z
        * (
            4.1666666666e-2
            + z * (-1.3888888888e-3 + z * (2.4801587301e-5 + z * (-2.7557319223e-7 + z * 2.0876756987e-9)))
        )
    )
    width = jnp.finfo(x.dtype).bits
    int_dtype = jnp.dtype(f"int{width}")
    sign_bit = jax.lax.shift_left(n.astype(int_dtype), jnp.asarray(width - 1, int_dtype))  # (-1)^n

    def times_sign(v):
        return jax.lax.bitcast_convert_type(jax.lax.bitcast_convert_type(v, int_dtype) ^ sign_bit, v.dtype)

    return times_sign(sin), times_sign(cos)


def signs_of(x: jax.Array, xi: jax.Array) -> jax.Array:
    """``sgn(xi x)`` in ``{-1, +1}`` (0 maps to +1): ``x (..., d)``, ``xi (r, d)`` -> ``(..., r)``."""
    return jnp.where(x @ xi.T >= 0, 1.0, -1.0).astype(x.dtype)


def feature_factors(x: jax.Array, projections: Projections) -> FeatureFactors:
    """Computes :class:`FeatureFactors` of ``x (..., d)`` for ``projections.omega`` ``(m, d)``."""
    projected = x @ drawn(projections.omega, "omega", "exp").T
    half_sq_norm = 0.5 * jnp.sum(x * x, axis=-1, keepdims=True)
    sin, cos = sincos(projected)
    return FeatureFactors(
        trig_log=half_sq_norm,
        sin=sin,
        cos=cos,
        exp_log=projected - half_sq_norm,
        signs=None if projections.xi is None else signs_of(x, projections.xi),
    )


def stabilizing_shift(factors: FeatureFactors, kind: str, stabilize: bool) -> jax.Array:
    """The log-scale subtracted from every feature of one set: ``(..., 1, 1)`` or scalar 0.

    The maximum log-magnitude over the set axis ``-2`` and every feature the kind uses, so
    the largest feature of each set is of order one; one constant per set keeps rankings.
    """
    if not stabilize:
        return jnp.zeros((), factors.exp_log.dtype)
    parts = []
    if kind in ("trig", "hybrid"):
        parts.append(jnp.max(factors.trig_log, axis=(-2, -1), keepdims=True))
    if kind in ("exp", "hybrid"):
        parts.append(jnp.max(factors.exp_log, axis=(-2, -1), keepdims=True))
    return jax.lax.stop_gradient(functools.reduce(jnp.maximum, parts))


def feature_map(kind: str, x: jax.Array, projections: Projections, *, role: str, stabilize: bool = False) -> jax.Array:
    """Features of queries or keys ``x (..., d)`` -> ``(..., M)`` (``M`` from :func:`feature_count`).

    ``feature_map(k, x, p, role="query") @ feature_map(k, y, p, role="key")`` is an unbiased
    estimate of ``exp(x.y)`` for ``exp``/``trig``/``hybrid``, of ``1 - 2 theta/pi`` for
    ``angular``, and exactly the ReLU kernel for ``relu``. Only ``hybrid`` depends on ``role``:
    its ``beta`` block enters with ``+`` for queries and ``-`` for keys (iap-math.md section 4).

    Args:
      kind: one of :data:`KINDS`.
      x: ``(..., d)`` queries or keys.
      projections: from :func:`draw_projections` with the same kind.
      role: ``"query"`` or ``"key"``.
      stabilize: subtract one log-shift per set (axis ``-2``, so ``x`` needs a set axis); see
        the module docstring. The estimate is then scaled by a positive per-set constant.

    Returns:
      ``(..., M)`` features.
    """
    check_kind(kind)
    check_role(role)
    if kind == "relu":
        return jax.nn.relu(x) + RELU_EPSILON
    if kind == "angular":
        signs = signs_of(x, drawn(projections.xi, "xi", "angular"))
        return signs / math.sqrt(signs.shape[-1])
    drawn(projections.omega, "omega", kind)
    if kind == "hybrid":
        drawn(projections.xi, "xi", kind)
    factors = feature_factors(x, projections)
    shift = stabilizing_shift(factors, kind, stabilize)
    m = factors.exp_log.shape[-1]
    trig = jnp.exp(factors.trig_log - shift) * jnp.concatenate([factors.sin, factors.cos], axis=-1)
    positive = jnp.exp(factors.exp_log - shift)
    if kind == "trig":
        return trig / math.sqrt(m)
    if kind == "exp":
        return positive / math.sqrt(m)
    signs = drawn(factors.signs, "xi", kind)
    r = signs.shape[-1]
    beta_sign = 1.0 if role == "query" else -1.0
    # alpha: (..., 2m, r) -> (..., 2mr); beta: (..., m, r) -> (..., mr).
    alpha = (trig[..., :, None] * signs[..., None, :]).reshape(*x.shape[:-1], 2 * m * r)
    beta = beta_sign * (positive[..., :, None] * signs[..., None, :]).reshape(*x.shape[:-1], m * r)
    blocks = [trig / math.sqrt(m), positive / math.sqrt(m), alpha / math.sqrt(m * r), beta / math.sqrt(m * r)]
    return jnp.concatenate(blocks, axis=-1) / math.sqrt(2.0)


def softmax_kernel(x: jax.Array, y: jax.Array) -> jax.Array:
    """``SM(x, y) = exp(x.y)`` for ``x, y (..., d)`` -> ``(...)``."""
    return jnp.exp(jnp.sum(x * y, axis=-1))


def angle_between(x: jax.Array, y: jax.Array) -> jax.Array:
    """The angle ``theta`` in ``[0, pi]`` between ``x, y (..., d)`` -> ``(...)``.

    Kahan's ``2 atan2(| |x| y - |y| x |, | |x| y + |y| x |)``, accurate near 0 and pi where
    ``arccos`` of the cosine loses half the float32 digits.
    """
    norm_x = jnp.linalg.norm(x, axis=-1, keepdims=True)
    norm_y = jnp.linalg.norm(y, axis=-1, keepdims=True)
    return 2.0 * jnp.arctan2(
        jnp.linalg.norm(norm_x * y - norm_y * x, axis=-1), jnp.linalg.norm(norm_x * y + norm_y * x, axis=-1)
    )


def closed_form_mse(kind: str, x: jax.Array, y: jax.Array, *, m: int, r: int | None = None) -> jax.Array:
    """Mean squared error of the ``exp(x.y)`` estimators with iid draws (iap-math.md section 5).

    Args:
      kind: ``"exp"``, ``"trig"`` or ``"hybrid"``.
      x, y: ``(..., d)`` inputs.
      m: number of random features; r: number of sign features (``hybrid`` only).

    Returns:
      ``(...)`` the MSE of ``feature_map(kind, x) . feature_map(kind, y)`` as an estimate of
      ``exp(x.y)`` when ``omega`` and ``xi`` are iid Gaussian (``orthogonal=False``).
    """
    require_choice("closed_form_mse's kind", kind, MSE_KINDS)
    m = _check_count("m", m)
    sm = softmax_kernel(x, y)
    sq_norm_sum = jnp.sum((x + y) ** 2, axis=-1)
    sq_norm_diff = jnp.sum((x - y) ** 2, axis=-1)
    mse_trig = jnp.exp(sq_norm_sum) / (2 * m * sm**2) * (1.0 - jnp.exp(-sq_norm_diff)) ** 2
    mse_exp = jnp.exp(sq_norm_sum) * sm**2 / m * (1.0 - jnp.exp(-sq_norm_sum))
    if kind == "trig":
        return mse_trig
    if kind == "exp":
        return mse_exp
    r = _check_count("r", r)
    p = angle_between(x, y) / jnp.pi
    norm_gap = jnp.sum(x * x, axis=-1) - jnp.sum(y * y, axis=-1)
    cross = (2.0 / m) * sm**2 * (1.0 - jnp.cos(norm_gap))
    return p * mse_exp + (1 - p) * mse_trig - p * (1 - p) * (1 - 1 / r) * (mse_exp + mse_trig + cross)
