"""Pixel observations as the pixel policies read them: an image ``(H, W, C)``, or a
``{"pixels", "state"}`` dict (``obs_mode="pixels+state"`` / ``"depth+state"``)."""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp


def split_observation(obs: Any) -> tuple[jax.Array, jax.Array | None]:
    """``(pixels (H, W, C), state (n,) or None)`` from an array or a ``{"pixels", "state"}`` dict."""
    if isinstance(obs, dict):
        return obs["pixels"], jnp.ravel(obs["state"])
    return obs, None


def required_state(state: jax.Array | None) -> jax.Array:
    """``state`` of :func:`split_observation`, which a policy with ``state_size > 0`` needs;
    ``ValueError`` without one."""
    if state is None:
        raise ValueError(
            "this policy has state_size > 0 and needs {'pixels': ..., 'state': ...} observations "
            "(obs_mode 'pixels+state' or 'depth+state')"
        )
    return state


def pixel_shape(observation_shape: Any) -> tuple[tuple[int, int, int], int]:
    """``((H, W, C), state_size)`` of an env's observation shape (array or pixels+state dict)."""
    if isinstance(observation_shape, dict):
        pixels = tuple(observation_shape["pixels"])
        state_size = int(math.prod(observation_shape["state"]))
    else:
        pixels, state_size = tuple(observation_shape), 0
    if len(pixels) != 3:
        raise ValueError(
            f"a pixel policy needs (H, W, C) observations, got {observation_shape!r}; "
            "make the env with a pixel obs_mode: 'pixels', 'pixels_depth', 'pixels+state' or "
            "'depth+state' (iap_mjx.configs.env.PIXEL_MODES)"
        )
    height, width, channels = pixels
    return (int(height), int(width), int(channels)), state_size
