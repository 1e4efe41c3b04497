"""The convolutional policies, and what "cnn" names where:

- :class:`ConvNet`, the CNN high level of the paper's quadruped experiment (its appendix A.2;
  the hierarchical policy's ``high_level="cnn"``, preset ``quadruped-walls-cnn``);
- :class:`ConvNetPolicy`, policy kind ``"convnet"``: the same convolutions and pool as a flat
  policy on the Distracting Control Suite, its embedding read by IAP's controller (presets
  ``dcs-<task>-cnn``, ``reproduce table1 --policy cnn``).

:class:`ConvNet` is three convolutions of small filters, a pooling layer, a fully connected
``tanh`` layer, and an output clipped to ``[-1, 1]``. The paper's text gives no sizes; ours (its
defaults) on the course's 24x32 RGB camera: 3x3 filters with 8, 16 and 16 channels at strides
2, 2 and 1 ("SAME" padding, ReLU), so 24x32 -> 12x16x8 -> 6x8x16 -> 6x8x16; a 2x2 max pool ->
3x4x16 = 192 numbers; a 16-unit ``tanh`` layer; a linear output clipped to ``[-1, 1]``. The
pool is local, not global: the flattened 3x4 grid keeps *where* in the image a wall is, which
is what steering needs (a global average would keep only *what*). With 5 outputs
(a duration and a 4-d latent command) that is 6,885 parameters.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp

from iap_mjx.checks import require_int
from iap_mjx.chunks import ceil_div
from iap_mjx.policies.base import check_options, check_sizes, constructor_options, lists_as_tuples
from iap_mjx.policies.controller import Controller
from iap_mjx.policies.mlp import apply_dense_layers, init_dense_layers
from iap_mjx.policies.observations import pixel_shape, required_state, split_observation


@dataclasses.dataclass(frozen=True)
class ConvFeatures:
    """Convolutions -> max pool -> flatten (+ state): the part :class:`ConvNet` and
    :class:`ConvNetPolicy` share (each holds its own parameters and what follows).

    Attributes:
      image_shape: ``(H, W, C)`` of the pixel observation.
      channels: output channels of the convolutions (ReLU), one entry per layer.
      strides: their strides, one per layer.
      filter_size: the convolutions' square filter side.
      pool: side (and stride) of the max pool after the last convolution.
      state_size: length of a state vector concatenated to the flattened pool (0: none).
      owner: the class whose settings these are, as error messages name them.
    """

    image_shape: tuple[int, int, int]
    channels: tuple[int, ...]
    strides: tuple[int, ...]
    filter_size: int
    pool: int
    state_size: int
    owner: str

    def __post_init__(self):
        check_sizes(self.owner, "channels", self.channels, non_empty=True)
        check_sizes(self.owner, "strides", self.strides, non_empty=True)
        if len(self.strides) != len(self.channels):
            raise ValueError(
                f"{self.owner}.strides must be one stride per convolution (channels = {self.channels!r}), "
                f"got {self.strides!r}."
            )
        for name in ("filter_size", "pool"):
            require_int(f"{self.owner}.{name}", getattr(self, name))
        require_int(f"{self.owner}.state_size", self.state_size, 0)
        rows, cols = self.pooled_grid
        if rows < 1 or cols < 1:
            raise ValueError(
                f"{self.owner}: a {self.image_shape[:2]} image shrinks to nothing under strides "
                f"{self.strides} and a {self.pool}x{self.pool} pool; use smaller strides or pool"
            )

    @classmethod
    def of(cls, settings: Any, owner: str) -> ConvFeatures:
        """The features set by the same-named fields of ``settings`` (a :class:`ConvNet` or a
        :class:`ConvNetPolicy`), ``owner`` naming it in error messages."""
        fields = (settings.channels, settings.strides, settings.filter_size, settings.pool, settings.state_size)
        return cls(tuple(settings.image_shape), *fields, owner)

    @property
    def pooled_grid(self) -> tuple[int, int]:
        """``(rows, cols)`` after the convolutions ("SAME": ``ceil(size / stride)``) and the pool."""
        rows, cols = self.image_shape[:2]
        for stride in self.strides:
            rows, cols = ceil_div(rows, stride), ceil_div(cols, stride)
        return rows // self.pool, cols // self.pool

    @property
    def flat_size(self) -> int:
        """The flattened output: the pooled grid's ``rows x cols x channels[-1]`` (+ state)."""
        rows, cols = self.pooled_grid
        return rows * cols * self.channels[-1] + self.state_size

    def init(self, keys: jax.Array) -> list[dict[str, jax.Array]]:
        """``keys (len(channels), 2)`` -> ``[{"w": (f, f, in, out), "b": (out,)}]``, one layer per
        key (:func:`init_convolutions`)."""
        return init_convolutions(keys, self.image_shape[2], self.channels, self.filter_size)

    def embed(self, conv: list[dict[str, jax.Array]], obs: Any) -> jax.Array:
        """The convolutions, the pool and any state: ``(flat_size,)``."""
        pixels, state = split_observation(obs)
        x = apply_convolutions(conv, pixels[None], self.strides, jax.nn.relu)
        window = (1, self.pool, self.pool, 1)
        x = jax.lax.reduce_window(x, -jnp.inf, jax.lax.max, window, window, "VALID")
        features = jnp.ravel(x)
        if self.state_size:
            features = jnp.concatenate([features, required_state(state)])
        return features


@dataclasses.dataclass(frozen=True)
class ConvNet:
    """Convolutions -> max pool -> flatten (+ state) -> dense ``tanh`` -> linear, clipped.

    Attributes:
      image_shape: ``(H, W, C)`` of the pixel observation.
      output_size: outputs in ``[-1, 1]`` (clipped, not squashed).
      channels, strides, filter_size, pool, state_size: the :class:`ConvFeatures`.
      hidden_size: the fully connected ``tanh`` layer.
    """

    image_shape: tuple[int, int, int]
    output_size: int
    channels: tuple[int, ...] = (8, 16, 16)
    strides: tuple[int, ...] = (2, 2, 1)
    filter_size: int = 3
    pool: int = 2
    hidden_size: int = 16
    state_size: int = 0

    def __post_init__(self):
        require_int("ConvNet.output_size", self.output_size)
        require_int("ConvNet.hidden_size", self.hidden_size)
        _ = self.body  # checks the convolutions' settings

    @property
    def body(self) -> ConvFeatures:
        """The convolutions and pool."""
        return ConvFeatures.of(self, "ConvNet")

    def init(self, key: jax.Array) -> dict[str, Any]:
        """``{"conv": [{"w": (f, f, in, out), "b": (out,)}], "dense": [(flat, hidden), (hidden,
        output)]}``: LeCun-normal weights, zero biases."""
        keys = jax.random.split(key, len(self.channels) + 1)
        body = self.body
        conv = body.init(keys[:-1])
        dense = init_dense_layers(keys[-1], (body.flat_size, self.hidden_size, self.output_size))
        return {"conv": conv, "dense": dense}

    def initial_state(self, key: jax.Array) -> tuple:
        """Stateless: the empty tuple."""
        del key
        return ()

    def apply(self, params: dict[str, Any], obs: Any, policy_state: tuple) -> tuple[jax.Array, tuple]:
        """``obs`` (pixels ``(H, W, C)`` or ``{"pixels", "state"}``) -> ``(output
        (output_size,) in [-1, 1], policy_state)``."""
        out = apply_dense_layers(params["dense"], self.body.embed(params["conv"], obs), jnp.tanh)
        return jnp.clip(out, -1.0, 1.0), policy_state


def apply_convolutions(
    conv: list[dict[str, jax.Array]], x: jax.Array, strides: tuple[int, ...], activation: Any
) -> jax.Array:
    """``x`` ``(1, H, W, C)`` through each layer of ``conv`` ("SAME" padding at its stride,
    then ``activation``): ``(1, ceil(H / s), ceil(W / s), channels[-1])``, ``s`` the strides'
    product."""
    for layer, stride in zip(conv, strides):
        x = jax.lax.conv_general_dilated(
            x, layer["w"], (stride, stride), "SAME", dimension_numbers=("NHWC", "HWIO", "NHWC")
        )
        x = activation(x + layer["b"])
    return x


def init_convolutions(
    keys: jax.Array, in_channels: int, channels: tuple[int, ...], filter_size: int
) -> list[dict[str, jax.Array]]:
    """One ``{"w": (f, f, in, out), "b": (out,)}`` per entry of ``channels`` (one key each):
    LeCun-normal weights, zero biases."""
    ins = (in_channels, *channels[:-1])
    f = filter_size
    return [
        {
            "w": jax.random.normal(k, (f, f, c_in, c_out), jnp.float32) / math.sqrt(f * f * c_in),
            "b": jnp.zeros((c_out,), jnp.float32),
        }
        for k, c_in, c_out in zip(keys, ins, channels)
    ]


@dataclasses.dataclass(frozen=True)
class ConvNetPolicy:
    """The convolutional baseline of the Distracting Control experiments: :class:`ConvNet`'s
    convolutions and pool -> a dense ``tanh`` embedding -> the IAP policy's controller.

    With the same controller as :class:`~iap_mjx.policies.iap.IAPPolicy` (an LSTM in the
    ``dcs-*`` presets), a comparison of the two differs in the features alone. The defaults
    suit the suite's 240x320 frames: 3x3 filters with 8, 16 and 16 channels at strides 4, 4 and
    2 (240x320 -> 60x80 -> 15x20 -> 8x10), a 2x2 max pool (4x5x16 = 320 numbers, the grid
    keeping where things are), a 16-unit embedding.

    Attributes:
      image_shape: ``(H, W, C)``; action_size: actions in ``[-1, 1]``.
      channels, strides, filter_size, pool: the :class:`ConvFeatures`.
      embedding_size: the dense ``tanh`` layer between the pool and the controller.
      controller, hidden_sizes, activation: the :class:`~iap_mjx.policies.controller.Controller`.
      state_size: length of the state vector of ``"pixels+state"`` observations (else 0).
    """

    image_shape: tuple[int, int, int]
    action_size: int
    channels: tuple[int, ...] = (8, 16, 16)
    strides: tuple[int, ...] = (4, 4, 2)
    filter_size: int = 3
    pool: int = 2
    embedding_size: int = 16
    controller: str = "lstm"
    hidden_sizes: tuple[int, ...] = (16,)
    activation: str = "tanh"
    state_size: int = 0

    def __post_init__(self):
        require_int("ConvNetPolicy.action_size", self.action_size)
        require_int("ConvNetPolicy.embedding_size", self.embedding_size)
        _ = self.body, self.head  # build both, which checks their settings

    @property
    def body(self) -> ConvFeatures:
        """The convolutions and pool (the embedding and the controller are this policy's own)."""
        return ConvFeatures.of(self, "ConvNetPolicy")

    @property
    def head(self) -> Controller:
        return Controller(
            self.controller,
            self.embedding_size,
            self.action_size,
            self.hidden_sizes,
            self.activation,
            owner="ConvNetPolicy",
        )

    def init(self, key: jax.Array) -> dict[str, Any]:
        """``{"conv": [...], "embed": [dense (flat, embedding)], "controller": ...}``."""
        conv_key, embed_key, head_key = jax.random.split(key, 3)
        body = self.body
        return {
            "conv": body.init(jax.random.split(conv_key, len(self.channels))),
            "embed": init_dense_layers(embed_key, (body.flat_size, self.embedding_size)),
            "controller": self.head.init(head_key),
        }

    def initial_state(self, key: jax.Array):
        """The controller's carry (``(h, c)`` zeros for an LSTM, else ``()``)."""
        del key
        return self.head.initial_carry()

    def apply(self, params: dict[str, Any], obs: Any, policy_state):
        """One control step: ``obs`` -> ``(action (action_size,), policy_state)``."""
        (embed,) = params["embed"]
        features = jnp.tanh(self.body.embed(params["conv"], obs) @ embed["w"] + embed["b"])
        return self.head.apply(params["controller"], features, policy_state)


def make_convnet_policy(observation_shape: Any, action_size: int, **options: Any) -> ConvNetPolicy:
    """Factory for ``policies.make("convnet", ...)``."""
    check_options("convnet", options, constructor_options(ConvNetPolicy, "image_shape", "action_size", "state_size"))
    image_shape, state_size = pixel_shape(observation_shape)
    return ConvNetPolicy(image_shape, action_size, state_size=state_size, **lists_as_tuples(options))
