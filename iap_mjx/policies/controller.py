"""The controller that turns a feature vector into an action: linear, MLP or LSTM.

IAP's policy and the convolutional baseline share it, so that a comparison of the two differs
in the features alone (attended patch centres against a convolutional embedding), never in
what reads them.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from iap_mjx.checks import require_choice, require_int
from iap_mjx.policies.base import ACTIVATIONS, check_sizes
from iap_mjx.policies.mlp import apply_dense_layers, init_dense_layers

CONTROLLERS = ("linear", "mlp", "lstm")


@dataclasses.dataclass(frozen=True)
class Controller:
    """``features (input_size,)`` -> ``tanh`` action ``(output_size,)``, with an LSTM carry.

    Attributes:
      kind: ``"linear"``, ``"mlp"`` or ``"lstm"`` (Tang et al.'s choice; its carry ``(h, c)`` is
        per-episode policy state, zero at the start of every episode).
      input_size, output_size: the feature and action lengths.
      hidden_sizes: the MLP's hidden layers; the LSTM's size is the first one.
      activation: the MLP's hidden activation.
      owner: the policy's name, for error messages.
    """

    kind: str
    input_size: int
    output_size: int
    hidden_sizes: tuple[int, ...] = (16,)
    activation: str = "tanh"
    owner: str = "Controller"

    def __post_init__(self):
        require_choice(f"{self.owner}.controller", self.kind, CONTROLLERS)
        require_choice(f"{self.owner}.activation", self.activation, ACTIVATIONS)
        check_sizes(self.owner, "hidden_sizes", self.hidden_sizes, non_empty=self.kind == "lstm")
        require_int(f"{self.owner}.input_size", self.input_size)
        require_int(f"{self.owner}.output_size", self.output_size)

    def init(self, key: jax.Array) -> Any:
        """Linear/MLP: a list of dense layers. LSTM: ``{"cell": {"w": (n_in + h, 4h), "b":
        (4h,)}, "out": [dense layer h -> action]}``."""
        if self.kind == "lstm":
            cell_key, out_key = jax.random.split(key)
            hidden = self.hidden_sizes[0]
            (cell,) = init_dense_layers(cell_key, (self.input_size + hidden, 4 * hidden))
            return {"cell": cell, "out": init_dense_layers(out_key, (hidden, self.output_size))}
        sizes = (self.input_size, *(self.hidden_sizes if self.kind == "mlp" else ()), self.output_size)
        return init_dense_layers(key, sizes)

    def initial_carry(self) -> tuple[jax.Array, jax.Array] | tuple:
        """The LSTM's zero ``(h, c)``, each ``(hidden,)``; ``()`` for the stateless kinds."""
        if self.kind != "lstm":
            return ()
        zeros = jnp.zeros((self.hidden_sizes[0],), jnp.float32)
        return zeros, zeros

    def apply(self, params: Any, features: jax.Array, carry) -> tuple[jax.Array, Any]:
        """``(tanh action (output_size,), carry)`` for ``features (input_size,)``."""
        if self.kind != "lstm":
            out = apply_dense_layers(params, features, ACTIVATIONS[self.activation])
            return jnp.tanh(out), carry
        hidden, cell = carry
        layer = params["cell"]
        gates = jnp.concatenate([features, hidden]) @ layer["w"] + layer["b"]
        in_gate, forget_gate, candidate, out_gate = jnp.split(gates, 4)
        cell = jax.nn.sigmoid(forget_gate) * cell + jax.nn.sigmoid(in_gate) * jnp.tanh(candidate)
        hidden = jax.nn.sigmoid(out_gate) * jnp.tanh(cell)
        (head,) = params["out"]  # one dense layer, hidden -> action
        return jnp.tanh(hidden @ head["w"] + head["b"]), (hidden, cell)
