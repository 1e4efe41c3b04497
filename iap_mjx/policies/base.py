"""The policy protocol: trainable params, per-episode state, and ``apply``.

A policy is a frozen (hashable) dataclass holding only static settings, so it can be closed
over by ``jit``. The ES engine relies on three pure functions:

* ``init(key) -> params``: the trainable parameters, a pytree of float32 arrays.
* ``initial_state(key) -> policy_state``: per-episode, non-trainable state drawn from the
  episode's key (e.g. IAP's random projections, an LSTM's zero carry). Stateless policies
  return an empty tuple ``()``.
* ``apply(params, obs, policy_state) -> (action, policy_state)``: one control step for one
  episode (no batch axis; the engine ``vmap``-s it). Actions are in ``[-1, 1]``.
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Iterable, Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Protocol, TypeGuard

import jax
import jax.numpy as jnp

from iap_mjx.checks import require_int

if TYPE_CHECKING:
    from iap_mjx.attention import IAPAttention, Selection

Params = Any
PolicyState = Any


class Policy(Protocol):
    """What the ES engine relies on (see the module docstring).

    Optional members, read where present: ``select`` and ``layer``
    (:class:`AttendingPolicy`, :func:`attends`) make videos, strips and ``iap-mjx attended`` draw the selected
    patches; ``level_param_counts(params)`` (a hierarchy's parameters per level) is logged
    beside the total.
    """

    @property
    def action_size(self) -> int: ...

    def init(self, key: jax.Array) -> Params: ...

    def initial_state(self, key: jax.Array) -> PolicyState: ...

    def apply(self, params: Params, obs: Any, policy_state: PolicyState) -> tuple[jax.Array, PolicyState]: ...


class AttendingPolicy(Policy, Protocol):
    """A policy that selects patches of its camera image with an IAP layer: what videos,
    strips and ``iap-mjx attended`` draw the selected patches from (:func:`attends` tells)."""

    @property
    def layer(self) -> IAPAttention:
        """The attention layer the policy selects with."""
        ...

    def select(self, params: Params, obs: Any, policy_state: PolicyState) -> Selection:
        """The layer's selection for ``obs`` (one step, no batch axis)."""
        ...


def attends(policy: object) -> TypeGuard[AttendingPolicy]:
    """Whether ``policy`` has :class:`AttendingPolicy`'s ``select`` and ``layer``."""
    return hasattr(policy, "select") and hasattr(policy, "layer")


def param_count(params: Params) -> int:
    """The number of scalars in a params pytree."""
    return int(sum(jnp.size(leaf) for leaf in jax.tree_util.tree_leaves(params)))


def init_param_count(policy: Policy) -> int:
    """The number of scalars ``policy.init`` returns, counted from their shapes
    (``jax.eval_shape``: traced, nothing computed, so a report counts a CNN's without running
    its initialisers)."""
    return param_count(jax.eval_shape(policy.init, jax.random.PRNGKey(0)))


ACTIVATIONS = MappingProxyType(
    {
        "tanh": jnp.tanh,
        "relu": jax.nn.relu,
        "elu": jax.nn.elu,
        "gelu": jax.nn.gelu,
    }
)
"""The hidden layers' activations, by the name a policy's ``activation`` setting takes."""


def constructor_options(cls: type, *set_by_factory: str) -> set[str]:
    """The constructor arguments of ``cls`` that a ``policy.*`` option can set: all but
    ``set_by_factory``, those its factory passes itself (shapes, sizes, sub-configs)."""
    return set(inspect.signature(cls).parameters) - set(set_by_factory)


def lists_as_tuples(options: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` with every list value a tuple: a config from JSON or a command line gives
    lists, and the policies are frozen, hashable dataclasses whose sizes are tuples."""
    return {name: tuple(value) if isinstance(value, list) else value for name, value in options.items()}


def field_names(config_cls: type) -> set[str]:
    """The field names of the dataclass ``config_cls`` (a policy's sub-config, such as
    ``AttentionConfig``: a ``policy.*`` option can set each)."""
    return {f.name for f in dataclasses.fields(config_cls)}


def split_options(options: Mapping[str, Any], config_cls: type) -> tuple[dict[str, Any], dict[str, Any]]:
    """``options`` split in two: those that are fields of ``config_cls`` and the rest (the
    policy's own)."""
    fields = field_names(config_cls)
    own = {k: v for k, v in options.items() if k in fields}
    return own, {k: v for k, v in options.items() if k not in fields}


def check_options(kind: str, options: Mapping[str, Any], valid: Iterable[str]) -> None:
    """Raises ``ValueError`` naming the options of policy ``kind`` that are not among ``valid``,
    and the valid ones: a misspelt ``policy.*`` setting fails before anything is built."""
    valid = set(valid)
    unknown = sorted(set(options) - valid)
    if unknown:
        raise ValueError(f"policy.options {unknown} do not fit policy {kind!r}; valid: {sorted(valid)}")


def check_sizes(owner: str, field: str, value: Any, *, non_empty: bool = False) -> None:
    """Raises ``ValueError`` naming ``owner.field`` unless ``value`` is a tuple of positive ints
    (and not empty, if ``non_empty``)."""
    if not isinstance(value, tuple) or (non_empty and not value):
        raise ValueError(
            f"{owner}.{field} must be a {'non-empty ' if non_empty else ''}tuple of positive ints "
            f"(one entry: (32,) in Python, 32, on the command line), got {value!r}."
        )
    for size in value:
        require_int(f"{owner}.{field}[...]", size)
