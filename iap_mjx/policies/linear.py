"""Linear policy over a state vector: ``action = tanh(W obs + b)`` (ARS-style)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from iap_mjx.checks import require_bool, require_int


@dataclasses.dataclass(frozen=True)
class LinearPolicy:
    """``tanh(obs @ W + b)``; ``obs`` is ``(obs_size,)``, the action ``(action_size,)``.

    ``W`` starts at zero (as in ARS), so the initial policy outputs zero actions and the
    perturbations alone set the first search directions.
    """

    obs_size: int
    action_size: int
    zero_init: bool = True

    def __post_init__(self):
        require_int("LinearPolicy.obs_size", self.obs_size)
        require_int("LinearPolicy.action_size", self.action_size)
        require_bool("LinearPolicy.zero_init", self.zero_init)

    def init(self, key: jax.Array) -> dict[str, jax.Array]:
        """Returns ``{"w": (obs_size, action_size), "b": (action_size,)}``."""
        if self.zero_init:
            w = jnp.zeros((self.obs_size, self.action_size), jnp.float32)
        else:
            w = jax.random.normal(key, (self.obs_size, self.action_size), jnp.float32)
            w = w / jnp.sqrt(self.obs_size)
        return {"w": w, "b": jnp.zeros((self.action_size,), jnp.float32)}

    def initial_state(self, key: jax.Array) -> tuple:
        """Stateless: the empty tuple."""
        del key
        return ()

    def apply(self, params: dict[str, jax.Array], obs: jax.Array, policy_state: tuple) -> tuple[jax.Array, tuple]:
        """``obs`` ``(obs_size,)`` -> ``(action (action_size,), policy_state)``."""
        action = jnp.tanh(jnp.ravel(obs) @ params["w"] + params["b"])
        return action, policy_state
