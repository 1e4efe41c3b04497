"""Search strategies over a flat parameter vector: our OpenAI-ES and an evosax adapter.

A strategy is an object with pure functions (all shapes for ``D`` parameters, population
``P``):

* ``init(key, mean (D,)) -> state``
* ``ask(key, state) -> (population (P, D), state)``
* ``tell(key, population (P, D), fitness (P,), state) -> state``: higher fitness is better.
* ``mean(state) -> (D,)``: the centre, the params we evaluate and ship.
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Callable
from typing import Any, Protocol

import jax
import jax.numpy as jnp
import optax
from flax import struct

from iap_mjx.checks import require_choice
from iap_mjx.configs.training import EVOSAX_STRATEGIES
from iap_mjx.es.shaping import ShapingFn, centred_ranks, nan_to_worst


class Strategy(Protocol):
    """See the module docstring."""

    @property
    def population_size(self) -> int: ...

    def init(self, key: jax.Array, mean: jax.Array) -> Any: ...

    def ask(self, key: jax.Array, state: Any) -> tuple[jax.Array, Any]: ...

    def tell(self, key: jax.Array, population: jax.Array, fitness: jax.Array, state: Any) -> Any: ...

    def mean(self, state: Any) -> jax.Array: ...


class OpenESState(struct.PyTreeNode):
    """OpenAI-ES state: centre ``mean`` ``(D,)``, optax state, and the iteration count."""

    mean: jax.Array
    opt_state: optax.OptState
    iteration: jax.Array


def antithetic_noise(key: jax.Array, population_size: int, num_dims: int) -> jax.Array:
    """``(P, D)`` standard normal noise whose second half is the negated first half."""
    half = jax.random.normal(key, (population_size // 2, num_dims), jnp.float32)
    return jnp.concatenate([half, -half], axis=0)


def estimate_gradient(noise: jax.Array, weights: jax.Array, sigma: jax.Array | float) -> jax.Array:
    """The ES gradient estimate ``sum_i w_i eps_i / (P sigma)``.

    ``noise`` ``(P, D)`` are the standard-normal ``eps_i`` (population = mean + sigma eps),
    ``weights`` ``(P,)`` the (shaped) fitness. With raw fitness this is an unbiased estimate of
    the gradient of the Gaussian-smoothed objective ``E[F(mean + sigma eps)]``.
    """
    return weights @ noise / (noise.shape[0] * sigma)


@dataclasses.dataclass(frozen=True, eq=False)
class OpenES:
    """OpenAI-ES (Salimans et al. 2017): Gaussian perturbations of one centre, maximising.

    Attributes:
      population_size: ``P`` (even when ``antithetic``).
      sigma: perturbation std, a float or an optax schedule of the iteration.
      optimizer: applied to the negated gradient estimate (we ascend).
      shaping: fitness ``(P,)`` -> weights ``(P,)``.
      weight_decay: ``c`` in ``grad - c * mean`` (an L2 pull towards zero).
      antithetic: mirrored sampling ``eps, -eps``.
    """

    population_size: int
    sigma: float | Callable[[jax.Array], jax.Array] = 0.02
    optimizer: optax.GradientTransformation = dataclasses.field(default_factory=lambda: optax.adam(0.01))
    shaping: ShapingFn = centred_ranks
    weight_decay: float = 0.0
    antithetic: bool = True

    def __post_init__(self):
        if self.antithetic and self.population_size % 2:
            raise ValueError(f"population_size = {self.population_size} must be even with antithetic sampling")

    def sigma_at(self, iteration: jax.Array) -> jax.Array:
        """The perturbation std at ``iteration``."""
        if callable(self.sigma):
            return jnp.asarray(self.sigma(iteration), jnp.float32)
        return jnp.asarray(self.sigma, jnp.float32)

    def init(self, key: jax.Array, mean: jax.Array) -> OpenESState:
        del key
        mean = jnp.asarray(mean, jnp.float32)
        return OpenESState(
            mean=mean,
            opt_state=self.optimizer.init(mean),
            iteration=jnp.zeros((), jnp.int32),
        )

    def noise(self, key: jax.Array, num_dims: int) -> jax.Array:
        """``(P, D)`` standard-normal perturbation directions for one iteration."""
        if self.antithetic:
            return antithetic_noise(key, self.population_size, num_dims)
        return jax.random.normal(key, (self.population_size, num_dims), jnp.float32)

    def ask(self, key: jax.Array, state: OpenESState) -> tuple[jax.Array, OpenESState]:
        eps = self.noise(key, state.mean.shape[0])
        return state.mean + self.sigma_at(state.iteration) * eps, state

    def tell(self, key: jax.Array, population: jax.Array, fitness: jax.Array, state: OpenESState) -> OpenESState:
        del key
        sigma = self.sigma_at(state.iteration)
        eps = (population - state.mean) / sigma
        grad = estimate_gradient(eps, self.shaping(fitness), sigma)
        grad = grad - self.weight_decay * state.mean
        updates, opt_state = self.optimizer.update(-grad, state.opt_state, state.mean)
        return OpenESState(
            mean=optax.apply_updates(state.mean, updates),
            opt_state=opt_state,
            iteration=state.iteration + 1,
        )

    def mean(self, state: OpenESState) -> jax.Array:
        return state.mean


def usable_evosax_algorithm(algorithm: type) -> bool:
    """Whether an evosax algorithm class fits :class:`EvosaxStrategy`: one population around one
    mean (``get_mean``). The population-based ones (``SimpleGA``, ``PSO``, ...) keep no mean;
    the Stein variational ones (``SV_*``) keep ``num_populations`` means and ask for
    ``num_populations x P`` members."""
    return hasattr(algorithm, "get_mean") and "num_populations" not in inspect.signature(algorithm).parameters


@dataclasses.dataclass(frozen=True, eq=False)
class EvosaxStrategy:
    """A distribution-based evosax algorithm behind our interface (evosax minimises).

    Attributes:
      name: one of ``configs.training.EVOSAX_STRATEGIES``, e.g. ``"CMA_ES"``, ``"SNES"``.
      population_size: ``P``.
      num_dims: ``D``.
      sigma: the initial std, written to the algorithm's ``std_init`` param when it has one.
      options: extra keyword arguments for the algorithm's constructor.
    """

    name: str
    population_size: int
    num_dims: int
    sigma: float = 0.02
    options: tuple[tuple[str, Any], ...] = ()
    # the evosax algorithm and its parameters, built from the fields above in __post_init__
    _algo: Any = dataclasses.field(init=False, repr=False)
    _params: Any = dataclasses.field(init=False, repr=False)

    def _algorithm(self):
        from evosax.algorithms import algorithms

        if self.name in algorithms and not usable_evosax_algorithm(algorithms[self.name]):
            raise ValueError(
                f"evosax strategy {self.name!r} is not one population around one mean ((P, D) "
                f"members, a (D,) mean); choose from {', '.join(EVOSAX_STRATEGIES)}"
            )
        require_choice("es.strategy", self.name, EVOSAX_STRATEGIES)
        try:
            return algorithms[self.name](
                population_size=self.population_size,
                solution=jnp.zeros((self.num_dims,), jnp.float32),
                **dict(self.options),
            )
        except TypeError as error:  # a missing or unknown constructor argument
            raise ValueError(f"es.evosax_options {dict(self.options)} for {self.name!r}: {error}") from None

    def __post_init__(self):
        algorithm = self._algorithm()
        object.__setattr__(self, "_algo", algorithm)
        params = algorithm.default_params
        if hasattr(params, "std_init"):
            params = params.replace(std_init=jnp.asarray(self.sigma, jnp.float32))
        object.__setattr__(self, "_params", params)

    def init(self, key: jax.Array, mean: jax.Array) -> Any:
        return self._algo.init(key, jnp.asarray(mean, jnp.float32), self._params)

    def ask(self, key: jax.Array, state: Any) -> tuple[jax.Array, Any]:
        return self._algo.ask(key, state, self._params)

    def tell(self, key: jax.Array, population: jax.Array, fitness: jax.Array, state: Any) -> Any:
        # A NaN fitness ranks below the worst finite one (as centred ranks put it); evosax
        # minimises, so negate.
        loss = -nan_to_worst(fitness, margin=1.0)
        state, _ = self._algo.tell(key, population, loss, state, self._params)
        return state

    def mean(self, state: Any) -> jax.Array:
        return state.mean
