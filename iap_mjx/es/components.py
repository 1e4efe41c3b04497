"""The built pieces of a run: ``build(config) -> Components`` (env, policy, strategy, mesh,
the population evaluator) and ``init_state(parts) -> TrainState``, the state before iteration 0.

The iteration (:mod:`iap_mjx.es.iteration`), the host's bookkeeping
(:mod:`iap_mjx.es.bookkeeping`), loading and evaluating runs (:mod:`iap_mjx.es.results`) and
``train`` itself all take their pieces from one ``Components``. The strategy searches the
policy's params as one flat vector ``(num_dims,)``; ``unravel`` turns it back into the pytree.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct
from jax.flatten_util import ravel_pytree
from jax.sharding import NamedSharding, PartitionSpec

from iap_mjx.configs.training import OPEN_ES, OPTIMIZER_NAMES, ESConfig, TrainConfig, one_per_name
from iap_mjx.es.episode import EpisodeResult
from iap_mjx.es.normalizer import ObsStats, init_stats
from iap_mjx.es.rollout import make_mesh, make_rollout, padded_share
from iap_mjx.es.shaping import SHAPINGS
from iap_mjx.es.strategy import EvosaxStrategy, OpenES, Strategy
from iap_mjx.policies.base import Policy

if TYPE_CHECKING:  # iap_mjx.envs is imported only where an env is built
    from iap_mjx.envs.base import Env

# Every random draw descends from ``run.seed`` through one of these streams (``fold_in``), so
# the training and evaluation draws never share a key with each other or with initialisation
# (whose one key both the policy's and the strategy's ``init`` take).
TRAIN_STREAM, EVAL_STREAM, INIT_STREAM = 0, 1, 2


class TrainState(struct.PyTreeNode):
    """Everything a run needs to continue: strategy state, observation statistics, the base
    key (constant) and the number of iterations done (``()`` int32; OpenES's state counts its
    own, equal to it, for the sigma schedule)."""

    strategy_state: Any
    obs_stats: ObsStats
    key: jax.Array
    iteration: jax.Array


@dataclasses.dataclass(frozen=True, eq=False)
class Components:
    """The built pieces of a run (shared by ``train``, ``evaluate_run`` and benchmarks)."""

    config: TrainConfig
    env: Env
    policy: Policy
    strategy: Strategy
    template_params: Any
    unravel: Callable[[jax.Array], Any]
    num_dims: int
    mesh: Any
    rollout: Callable[..., EpisodeResult]

    @property
    def replicated(self) -> NamedSharding:
        """A copy of the whole array on every device of the mesh: where the training state,
        the compiled calls' outputs and a restored checkpoint live."""
        return NamedSharding(self.mesh, PartitionSpec())

    @property
    def steps_per_iteration(self) -> int:
        """Training env steps per iteration (members x episodes x horizon, ``env.step`` calls,
        one action each): the sample budget. dm_control's count (PlaNet's, DrQ's) is this times
        the task's action repeat."""
        es = self.config.es
        return es.population_size * es.n_episodes * self.env.episode_length

    @property
    def simulated_steps_per_iteration(self) -> int:
        """Env steps actually simulated per iteration: training, centre evaluation and the
        padding that evens out the devices' shares."""
        es, run = self.config.es, self.config.run
        rows = es.population_size * es.n_episodes + run.eval_episodes
        share = padded_share(rows, self.mesh.devices.size, run.chunk_size)
        return share * self.mesh.devices.size * self.env.episode_length


def make_sigma(es: ESConfig, iterations: int) -> float | Callable[[jax.Array], jax.Array]:
    """The perturbation std: a constant or an optax schedule over ``iterations``."""
    if es.sigma_schedule == "linear":
        return optax.linear_schedule(es.sigma, es.sigma_final, iterations)
    if es.sigma_schedule == "exponential":
        return optax.exponential_decay(es.sigma, iterations, es.sigma_final / es.sigma)
    return es.sigma


_OPTIMIZERS: dict[str, Callable[[float], optax.GradientTransformation]] = one_per_name(
    OPTIMIZER_NAMES,
    {
        "adam": optax.adam,
        "sgd": optax.sgd,
        "momentum": lambda learning_rate: optax.sgd(learning_rate, momentum=0.9),
    },
)
"""The optax optimizer of each ``ESConfig.optimizer`` name given its learning rate (the names'
one home: ``configs.training.OPTIMIZER_NAMES``)."""


def make_optimizer(es: ESConfig) -> optax.GradientTransformation:
    """The optax optimizer named by ``es.optimizer``."""
    return _OPTIMIZERS[es.optimizer](es.learning_rate)


def make_strategy(es: ESConfig, num_dims: int, iterations: int) -> Strategy:
    """Our OpenES, or the named evosax strategy behind the adapter."""
    if es.strategy == OPEN_ES:
        return OpenES(
            population_size=es.population_size,
            sigma=make_sigma(es, iterations),
            optimizer=make_optimizer(es),
            shaping=SHAPINGS[es.shaping],
            weight_decay=es.weight_decay,
            antithetic=es.antithetic,
        )
    return EvosaxStrategy(
        name=es.strategy,
        population_size=es.population_size,
        num_dims=num_dims,
        sigma=es.sigma,
        options=es.evosax_options,
    )


def make_env_and_policy(
    config: TrainConfig, *, env: Env | None = None, policy: Policy | None = None
) -> tuple[Env, Policy]:
    """The env and policy ``config`` names, built (nothing compiled): the policy sized to the
    env's observations and actions. A given ``env`` or ``policy`` is used instead (your own
    env: the config's policy kind is sized to it)."""
    from iap_mjx import policies

    if env is None:
        from iap_mjx import envs

        env = envs.make_spec(config.env)
    if policy is None:
        policy = policies.make(
            config.policy.kind,
            env.observation_shape,
            env.action_size,
            **dict(config.policy.options),
        )
    return env, policy


def build(
    config: TrainConfig, *, env: Env | None = None, policy: Policy | None = None, devices: Any = None
) -> Components:
    """Builds env, policy, strategy and the compiled-to-be evaluators for ``config``.

    ``env``/``policy`` override the ones the config names (:func:`make_env_and_policy`: your
    own env, tests, notebooks); ``devices`` overrides ``jax.devices()`` for the population mesh.
    """
    env, policy = make_env_and_policy(config, env=env, policy=policy)
    if config.es.normalize_observations and not (
        isinstance(env.observation_shape, tuple) and len(env.observation_shape) == 1
    ):
        raise ValueError(
            "es.normalize_observations = True needs vector observations, got shape "
            f"{env.observation_shape!r}; set es.normalize_observations=false"
        )
    template = policy.init(jax.random.fold_in(jax.random.PRNGKey(config.run.seed), INIT_STREAM))
    flat, unravel = ravel_pytree(template)
    mesh = make_mesh(config.run.num_devices, devices)
    check_chunk_size(config.run.chunk_size, env, mesh.devices.size)
    track = config.es.normalize_observations
    rollout = make_rollout(env, policy, unravel, mesh, config.run.chunk_size, track)
    strategy = make_strategy(config.es, flat.shape[0], config.run.iterations)
    return Components(config, env, policy, strategy, template, unravel, flat.shape[0], mesh, rollout)


def describe_parameters(parts: Components) -> str:
    """``"873 parameters (high 489, low 384)"``: the policy's trainable scalars, per level for a
    policy that has levels (``level_param_counts``)."""
    text = f"{parts.num_dims} parameters"
    levels = getattr(parts.policy, "level_param_counts", None)
    if levels is not None:
        text += " (" + ", ".join(f"{name} {count}" for name, count in levels(parts.template_params).items()) + ")"
    return text


def check_chunk_size(chunk_size: int, env: Env, num_devices: int) -> None:
    """Refuses ``run.chunk_size`` above the env's ``max_chunk_size`` on two or more devices,
    where a larger vmapped batch deadlocks XLA:CPU (``iap_mjx.envs.dmc.serial_lapack_batch``)."""
    limit = getattr(env, "max_chunk_size", None)
    if num_devices > 1 and limit is not None and chunk_size > limit:
        raise ValueError(
            f"run.chunk_size = {chunk_size} is too large for this env on {num_devices} devices: "
            f"valid values are 1..{limit}. With this jaxlib a larger vmapped batch splits MJX's "
            "batched Cholesky over XLA's thread pool and deadlocks XLA:CPU "
            "(see iap_mjx.envs.dmc.serial_lapack_batch)."
        )


def init_state(parts: Components) -> TrainState:
    """The state before iteration 0 (replicated over the mesh)."""
    config = parts.config
    key = jax.random.PRNGKey(config.run.seed)
    flat, _ = ravel_pytree(parts.template_params)
    obs_size = int(np.prod(parts.env.observation_shape)) if config.es.normalize_observations else 1

    def make():
        return TrainState(
            strategy_state=parts.strategy.init(jax.random.fold_in(key, INIT_STREAM), flat),
            obs_stats=init_stats(obs_size),
            key=key,
            iteration=jnp.zeros((), jnp.int32),
        )

    return jax.jit(make, out_shardings=parts.replicated)()
