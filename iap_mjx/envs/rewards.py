"""``dm_control.utils.rewards.tolerance`` in JAX: the shaping every dm_control task reward uses.

Same arguments, same validation, same values (``where``-based, so ``inf`` bounds work and no
Python control flow touches traced values).
"""

from __future__ import annotations

import math

import jax.numpy as jnp

SIGMOIDS = (
    "gaussian",
    "hyperbolic",
    "long_tail",
    "reciprocal",
    "cosine",
    "linear",
    "quadratic",
    "tanh_squared",
)
_DEFAULT_VALUE_AT_MARGIN = 0.1


def _sigmoid(x: jnp.ndarray, value_at_1: float, sigmoid: str) -> jnp.ndarray:
    """1 at ``x == 0``, ``value_at_1`` at ``|x| == 1``, in ``[0, 1]`` elsewhere; shape of ``x``."""
    if sigmoid in ("cosine", "linear", "quadratic"):
        if not 0 <= value_at_1 < 1:
            raise ValueError(f"value_at_margin must be in [0, 1) for sigmoid={sigmoid!r}, got {value_at_1}.")
    elif sigmoid in SIGMOIDS:
        if not 0 < value_at_1 < 1:
            raise ValueError(f"value_at_margin must be in (0, 1) for sigmoid={sigmoid!r}, got {value_at_1}.")
    else:
        raise ValueError(f"sigmoid must be one of {SIGMOIDS}, got {sigmoid!r}.")

    if sigmoid == "gaussian":
        scale = math.sqrt(-2 * math.log(value_at_1))
        return jnp.exp(-0.5 * (x * scale) ** 2)
    if sigmoid == "hyperbolic":
        scale = math.acosh(1 / value_at_1)
        return 1 / jnp.cosh(x * scale)
    if sigmoid == "long_tail":
        scale = math.sqrt(1 / value_at_1 - 1)
        return 1 / ((x * scale) ** 2 + 1)
    if sigmoid == "reciprocal":
        scale = 1 / value_at_1 - 1
        return 1 / (jnp.abs(x) * scale + 1)
    if sigmoid == "cosine":
        scaled_x = x * (math.acos(2 * value_at_1 - 1) / math.pi)
        return jnp.where(jnp.abs(scaled_x) < 1, (1 + jnp.cos(jnp.pi * scaled_x)) / 2, 0.0)
    if sigmoid == "linear":
        scaled_x = x * (1 - value_at_1)
        return jnp.where(jnp.abs(scaled_x) < 1, 1 - scaled_x, 0.0)
    if sigmoid == "quadratic":
        scaled_x = x * math.sqrt(1 - value_at_1)
        return jnp.where(jnp.abs(scaled_x) < 1, 1 - scaled_x**2, 0.0)
    scale = math.atanh(math.sqrt(1 - value_at_1))
    return 1 - jnp.tanh(x * scale) ** 2


def tolerance(
    x: jnp.ndarray,
    bounds: tuple[float, float] = (0.0, 0.0),
    margin: float = 0.0,
    sigmoid: str = "gaussian",
    value_at_margin: float = _DEFAULT_VALUE_AT_MARGIN,
) -> jnp.ndarray:
    """1 where ``x`` is inside ``bounds`` (inclusive), decaying with the distance outside.

    Args:
      x: any shape.
      bounds: ``(lower, upper)``, may be infinite or equal.
      margin: distance outside the bounds at which the value is ``value_at_margin``;
        0 makes the reward a hard indicator of ``bounds``.
      sigmoid: the decay shape, one of ``SIGMOIDS``.
      value_at_margin: see ``margin``; ignored when ``margin == 0``.

    Returns:
      Values in ``[0, 1]``, the shape of ``x``.
    """
    lower, upper = bounds
    if lower > upper:
        raise ValueError(f"bounds must have lower <= upper, got {bounds}.")
    if margin < 0:
        raise ValueError(f"margin must be non-negative, got {margin}.")
    x = jnp.asarray(x)
    in_bounds = jnp.logical_and(lower <= x, x <= upper)
    if margin == 0:
        return jnp.where(in_bounds, 1.0, 0.0)
    distance = jnp.where(x < lower, lower - x, x - upper) / margin
    return jnp.where(in_bounds, 1.0, _sigmoid(distance, value_at_margin, sigmoid))
