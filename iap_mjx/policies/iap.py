"""The IAP pixel policy: attention + controller (``kernel="brute"`` gives the brute-force
softmax baseline with the same controller).

IAP policy (paper section 3): the attention layer scores every patch of the image, keeps the
top ``l``, and the controller sees their centres (``2l`` numbers, optionally the patches'
pixels too), concatenated with any state sensors; actions are ``tanh`` of the controller's
output. Deterministic, as in the paper. With ``kernel="brute"`` and ``row_normalize=True``
the same policy is Tang et al.'s AttentionAgent (the "Brute" baseline).

Random projections are not trained: ``initial_state`` draws them from the episode key when
``redraw_projections`` is set, otherwise from the fixed ``projection_seed`` (the same draw in
every episode and every member of the population).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from iap_mjx.attention import AttentionConfig, IAPAttention
from iap_mjx.checks import require_bool, require_int
from iap_mjx.policies.base import check_options, constructor_options, field_names, lists_as_tuples, split_options
from iap_mjx.policies.controller import Controller
from iap_mjx.policies.observations import pixel_shape, required_state, split_observation


@dataclasses.dataclass(frozen=True)
class IAPPolicy:
    """Attention over patches -> ``l`` patch centres (+ patches, + state) -> controller -> tanh.

    Attributes:
      image_shape: ``(H, W, C)`` of the pixel observation.
      action_size: actions in ``[-1, 1]``.
      attention: the attention layer's settings (kernel, patch size, ``l``, ``m``, ``r``, ...).
      state_size: length of the state vector of ``"pixels+state"`` observations (else 0).
      controller: ``"linear"``, ``"mlp"`` or ``"lstm"`` (Tang et al.'s choice; its carry is
        per-episode policy state, zero at the start of every episode).
      hidden_sizes: the MLP controller's hidden layers; the LSTM's size is the first one.
      activation: the MLP controller's hidden activation.
      with_patches: also feed the selected patches' pixels to the controller.
      projection_seed: seed of the fixed random projections (unless redrawn per episode).
      redraw_projections: draw new random projections every episode (from the episode's key)
        instead of once.
    """

    image_shape: tuple[int, int, int]
    action_size: int
    attention: AttentionConfig = AttentionConfig()
    state_size: int = 0
    controller: str = "linear"
    hidden_sizes: tuple[int, ...] = (16,)
    activation: str = "tanh"
    with_patches: bool = False
    projection_seed: int = 0
    redraw_projections: bool = False

    def __post_init__(self):
        require_int("IAPPolicy.action_size", self.action_size)
        require_int("IAPPolicy.state_size", self.state_size, 0)
        require_int("IAPPolicy.projection_seed", self.projection_seed, 0)
        require_bool("IAPPolicy.with_patches", self.with_patches)
        require_bool("IAPPolicy.redraw_projections", self.redraw_projections)
        IAPAttention(self.attention, self.image_shape)  # raises before anything compiles
        _ = self.head  # builds the controller, which checks its settings

    @property
    def layer(self) -> IAPAttention:
        """The attention layer for this image shape."""
        return IAPAttention(self.attention, self.image_shape)

    @property
    def feature_size(self) -> int:
        """The controller's input size: ``2l`` (+ ``l p^2 C``) (+ ``state_size``)."""
        top_l = self.attention.top_l
        patches = top_l * self.layer.patch_dim if self.with_patches else 0
        return 2 * top_l + patches + self.state_size

    @property
    def head(self) -> Controller:
        """The controller over :attr:`feature_size` features."""
        return Controller(
            self.controller, self.feature_size, self.action_size, self.hidden_sizes, self.activation, owner="IAPPolicy"
        )

    def init(self, key: jax.Array) -> dict[str, Any]:
        """``{"attention": AttentionParams, "controller": Controller params}``."""
        attention_key, controller_key = jax.random.split(key)
        return {"attention": self.layer.init(attention_key), "controller": self.head.init(controller_key)}

    def initial_state(self, key: jax.Array):
        """``(projections, carry)``: the episode's random projections (fixed seed unless
        ``redraw_projections``) and the controller's zero carry (an LSTM's ``(h, c)``; ``()``
        for a stateless controller)."""
        if not self.redraw_projections:
            key = jax.random.PRNGKey(self.projection_seed)
        return self.layer.draw_projections(key), self.head.initial_carry()

    def features(self, params: dict[str, Any], obs: Any, projections) -> tuple[jax.Array, Any]:
        """The controller's input ``(feature_size,)`` and the layer's ``Selection``."""
        pixels, state = split_observation(obs)
        selection = self.layer(params["attention"], projections, pixels, with_patches=self.with_patches)
        parts = [selection.centres.reshape(-1)]
        if self.with_patches:
            assert selection.patches is not None  # the layer was asked for them
            parts.append(selection.patches.reshape(-1))
        if self.state_size:
            parts.append(required_state(state))
        return jnp.concatenate(parts), selection

    def apply(self, params: dict[str, Any], obs: Any, policy_state):
        """One env step: ``obs`` -> ``(action (action_size,), policy_state)``."""
        projections, carry = policy_state
        features, _ = self.features(params, obs, projections)
        action, carry = self.head.apply(params["controller"], features, carry)
        return action, (projections, carry)

    def select(self, params: dict[str, Any], obs: Any, policy_state):
        """The attention layer's ``Selection`` for ``obs`` (for videos and figures)."""
        projections, _ = policy_state
        return self.features(params, obs, projections)[1]


def make_iap_policy(observation_shape: Any, action_size: int, **options: Any) -> IAPPolicy:
    """Factory for ``policies.make("iap", ...)``: attention fields go to ``AttentionConfig``."""
    image_shape, state_size = pixel_shape(observation_shape)
    attention_options, rest = split_options(options, AttentionConfig)
    check_options(
        "iap",
        options,
        field_names(AttentionConfig)
        | constructor_options(IAPPolicy, "image_shape", "action_size", "attention", "state_size"),
    )
    attention = AttentionConfig(**attention_options)
    return IAPPolicy(image_shape, action_size, attention, state_size=state_size, **lists_as_tuples(rest))
