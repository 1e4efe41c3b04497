"""Policies: observation -> action (linear and MLP over states; IAP over pixels; PMTG,
a trajectory generator modulated by a linear policy, for the quadruped; the hierarchical
quadruped policy, a camera high level over the PMTG low level; the convolutional baseline
``convnet`` and the hierarchy's CNN high level, in :mod:`~iap_mjx.policies.convnet`, which says
what "cnn" names where).

``make(kind, observation_shape, action_size, **options)`` builds a policy by name from
:data:`FACTORIES` (read-only; a kind of this package is a row there), ``names()`` lists the
kinds. A factory takes ``(observation_shape, action_size, **options)``. A user's own policy
needs no name: ``es.train(config, policy=...)`` trains it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import Any

from iap_mjx.checks import require_choice
from iap_mjx.configs.training import POLICY_KINDS, one_per_name
from iap_mjx.policies.base import Policy, check_options, constructor_options, init_param_count, param_count
from iap_mjx.policies.convnet import ConvFeatures, ConvNet, ConvNetPolicy, make_convnet_policy
from iap_mjx.policies.hierarchical import HierarchicalPolicy, make_hierarchical_policy
from iap_mjx.policies.iap import IAPPolicy, make_iap_policy
from iap_mjx.policies.linear import LinearPolicy
from iap_mjx.policies.mlp import MLPPolicy
from iap_mjx.policies.pmtg import PMTGPolicy, make_pmtg_policy


def _flat_size(observation_shape: Any) -> int:
    if not isinstance(observation_shape, tuple):
        raise ValueError(f"this policy needs an array observation, got shape {observation_shape!r}")
    return int(math.prod(observation_shape))


def _flat_factory(kind: str, cls: type) -> Callable[..., Policy]:
    """The factory of a policy on a flat state vector: ``cls(obs_size, action_size, **options)``."""

    def factory(observation_shape: Any, action_size: int, **options: Any) -> Policy:
        check_options(kind, options, constructor_options(cls, "obs_size", "action_size"))
        return cls(_flat_size(observation_shape), action_size, **options)

    return factory


FACTORIES: Mapping[str, Callable[..., Policy]] = MappingProxyType(
    one_per_name(
        POLICY_KINDS,
        {
            "linear": _flat_factory("linear", LinearPolicy),
            "mlp": _flat_factory("mlp", MLPPolicy),
            "iap": make_iap_policy,
            "convnet": make_convnet_policy,
            "pmtg": make_pmtg_policy,
            "hierarchical": make_hierarchical_policy,
        },
    )
)
"""Each policy kind's factory, by name (the kinds are ``configs.training.POLICY_KINDS``)."""


def names() -> list[str]:
    """The policy kinds, sorted."""
    return sorted(FACTORIES)


def make(kind: str, observation_shape: Any, action_size: int, **options: Any) -> Policy:
    """Builds the policy ``kind`` for an env's observation shape and action size."""
    require_choice("policy.kind", kind, names())
    try:
        return FACTORIES[kind](observation_shape, action_size, **options)
    except TypeError as error:
        # a value of the wrong type (a number where sizes go) fails inside the constructor:
        # say which options, and keep the traceback
        raise ValueError(f"policy.options {options!r} do not fit policy {kind!r}: {error}") from error


__all__ = [
    "FACTORIES",
    "ConvFeatures",
    "ConvNet",
    "ConvNetPolicy",
    "HierarchicalPolicy",
    "IAPPolicy",
    "LinearPolicy",
    "MLPPolicy",
    "PMTGPolicy",
    "Policy",
    "init_param_count",
    "make",
    "names",
    "param_count",
]
