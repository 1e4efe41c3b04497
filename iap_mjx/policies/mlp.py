"""Multi-layer perceptron policy over a state vector, ``tanh`` actions."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from iap_mjx.checks import require_choice, require_int
from iap_mjx.policies.base import ACTIVATIONS, check_sizes


def init_dense_layers(key: jax.Array, sizes: tuple[int, ...]) -> list[dict[str, jax.Array]]:
    """LeCun-normal weights, zero biases for consecutive ``sizes`` (in, hidden..., out).

    Returns a list of ``{"w": (n_in, n_out), "b": (n_out,)}``, one per layer.
    """
    keys = jax.random.split(key, len(sizes) - 1)
    return [
        {
            "w": jax.random.normal(k, (n_in, n_out), jnp.float32) / jnp.sqrt(n_in),
            "b": jnp.zeros((n_out,), jnp.float32),
        }
        for k, n_in, n_out in zip(keys, sizes[:-1], sizes[1:])
    ]


def apply_dense_layers(layers, x: jax.Array, activation) -> jax.Array:
    """Hidden layers with ``activation``, the last layer linear. ``x`` ``(n_in,)``."""
    for layer in layers[:-1]:
        x = activation(x @ layer["w"] + layer["b"])
    last = layers[-1]
    return x @ last["w"] + last["b"]


@dataclasses.dataclass(frozen=True)
class MLPPolicy:
    """``tanh(MLP(obs))`` with hidden layers ``hidden_sizes``.

    ``obs`` is ``(obs_size,)`` (flattened if it has more axes), the action ``(action_size,)``.
    """

    obs_size: int
    action_size: int
    hidden_sizes: tuple[int, ...] = (32, 32)
    activation: str = "tanh"

    def __post_init__(self):
        require_int("MLPPolicy.obs_size", self.obs_size)
        require_int("MLPPolicy.action_size", self.action_size)
        check_sizes("MLPPolicy", "hidden_sizes", self.hidden_sizes)
        require_choice("MLPPolicy.activation", self.activation, ACTIVATIONS)

    def init(self, key: jax.Array) -> list[dict[str, jax.Array]]:
        """A list of ``{"w", "b"}`` layers, sizes ``obs -> hidden... -> action``."""
        sizes = (self.obs_size, *self.hidden_sizes, self.action_size)
        return init_dense_layers(key, sizes)

    def initial_state(self, key: jax.Array) -> tuple:
        """Stateless: the empty tuple."""
        del key
        return ()

    def apply(self, params, obs: jax.Array, policy_state: tuple):
        """``obs`` ``(obs_size,)`` -> ``(action (action_size,), policy_state)``."""
        out = apply_dense_layers(params, jnp.ravel(obs), ACTIVATIONS[self.activation])
        return jnp.tanh(out), policy_state
