"""A training run's configuration: ``TrainConfig`` and its four sections.

``TrainConfig(env=EnvSpec, policy=PolicySpec, es=ESConfig, run=RunConfig)``: which env (a
registry name and its ``EnvConfig`` overrides), which policy (a kind and its options), the
evolution strategy and the training loop. Frozen, hashable dataclasses validated on
construction: an invalid value raises ``ValueError`` naming the field and the valid values,
before anything is compiled.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from iap_mjx.checks import require_bool, require_choice, require_int, require_number

OPTIMIZER_NAMES = ("adam", "sgd", "momentum")
SHAPING_NAMES = ("centred_rank", "z_score", "identity")
"""The names ``es.optimizer`` and ``es.shaping`` take; ``iap_mjx.es`` builds its tables from
these (configs import nothing of ``es``, whose ``__init__`` loads orbax)."""
SIGMA_SCHEDULES = ("constant", "linear", "exponential")
OPEN_ES = "open_es"
EVOSAX_STRATEGIES = (
    "ARS", "ASEBO", "CMAAnchoredLES", "CMA_ES", "CR_FM_NES", "DES", "ESMC", "EvoTF_ES", "GradientlessDescent",
    "GuidedES", "HillClimbing", "LES", "LM_MA_ES", "MA_ES", "NoiseReuseES", "Open_ES", "PGPE", "PersistentES",
    "RandomSearch", "Rm_ES", "SNES", "Sep_CMA_ES", "SimpleES", "SimulatedAnnealing", "iAMaLGaM_Full",
    "iAMaLGaM_Univariate", "xNES",
)  # fmt: skip
"""evosax's distribution-based strategies that keep one population around one mean
(``evosax.algorithms.distribution_based_algorithms`` of the pinned evosax but the ``SV_*`` ones;
a test holds them equal), the other names ``es.strategy`` takes: listed here, since importing
evosax loads JAX. ``RandomSearch`` needs its ``sampling_fn`` in ``es.evosax_options``: a
function, so from Python only, and only without a run directory (``config.json`` cannot hold
a function)."""
POLICY_KINDS = ("convnet", "hierarchical", "iap", "linear", "mlp", "pmtg")
"""The names ``policy.kind`` takes; ``iap_mjx.policies`` builds its factory table from these
(so that configs, and the presets built at their import, load no JAX)."""
EVAL_SEED = 2021
"""The seed of a finished run's evaluations (``iap-mjx eval``, ``es.evaluate_run``, the paper's
tables): its episodes are fresh draws, none of them a training episode."""


def one_per_name(names: tuple[str, ...], table: dict[str, Any]) -> dict[str, Any]:
    """``table`` (name -> what ``iap_mjx.es`` or ``iap_mjx.policies`` builds for it), checked to hold exactly
    ``names``: a name added here without its entry there fails at import, not in a run."""
    if set(table) != set(names):
        raise ImportError(f"a table for the names {names} holds {tuple(table)}")
    return table


def _fail(owner: str, field: str, value: Any, why: str) -> None:
    """Raises ``ValueError`` in :mod:`iap_mjx.checks`' format: ``owner.field why, got value.``"""
    raise ValueError(f"{owner}.{field} {why}, got {value!r}.")


def _pairs(owner: str, field: str, value: Any) -> None:
    ok = isinstance(value, tuple) and all(isinstance(p, tuple) and len(p) == 2 and isinstance(p[0], str) for p in value)
    if not ok:
        _fail(owner, field, value, "must be a tuple of (name, value) pairs")
    try:
        hash(value)
    except TypeError:
        _fail(owner, field, value, "must hold hashable values (use tuples, not lists)")


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    """Which env: a name from ``iap_mjx.envs.names()`` and ``overrides`` of its settings
    (``iap_mjx.configs.EnvConfig`` fields, as ``(name, value)`` pairs) passed to ``make``."""

    name: str = "cheetah-run"
    overrides: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            _fail("env", "name", self.name, "must be a non-empty string")
        _pairs("env", "overrides", self.overrides)


@dataclasses.dataclass(frozen=True)
class PolicySpec:
    """Which policy: a kind from :data:`POLICY_KINDS` and its keyword options.

    On the command line ``policy.hidden_sizes=64,64`` sets an option (any name that is not a
    field of this class goes into ``options``).
    """

    kind: str = "mlp"
    options: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self):
        require_choice("policy.kind", self.kind, POLICY_KINDS)
        _pairs("policy", "options", self.options)


@dataclasses.dataclass(frozen=True)
class ESConfig:
    """The evolution strategy.

    Attributes:
      strategy: ``"open_es"`` (ours) or an evosax algorithm name such as ``"CMA_ES"``.
      population_size: perturbed members per iteration (even for antithetic OpenES).
      sigma: perturbation std (initial std for evosax strategies).
      sigma_schedule: ``constant``, or ``linear``/``exponential`` decay to ``sigma_final``
        over the run's iterations (OpenES only).
      sigma_final: the std reached at the last iteration when scheduled.
      optimizer: optax optimizer for the OpenES centre: ``adam``, ``sgd`` or ``momentum``.
      learning_rate: its step size.
      weight_decay: L2 pull ``grad - c * params`` (OpenES).
      shaping: fitness shaping: ``centred_rank``, ``z_score`` or ``identity``.
      antithetic: mirrored perturbations ``+eps, -eps`` (OpenES).
      n_episodes: episodes per member; fitness is their mean return.
      shared_episodes: every member runs the same ``n_episodes`` episodes in an iteration
        (the same env keys, drawn anew each iteration; EvoJAX trains so), so that members
        are ranked on equal draws (common random numbers), not each on its own draw's luck;
        ``False``: each member's episodes are its own.
      normalize_observations: running mean/std normalisation of vector observations,
        updated from every population rollout (Salimans et al.).
      evosax_options: extra constructor arguments for an evosax strategy.
    """

    strategy: str = OPEN_ES
    population_size: int = 256
    sigma: float = 0.02
    sigma_schedule: str = "constant"
    sigma_final: float = 0.01
    optimizer: str = "adam"
    learning_rate: float = 0.01
    weight_decay: float = 0.005
    shaping: str = "centred_rank"
    antithetic: bool = True
    n_episodes: int = 1
    shared_episodes: bool = False
    normalize_observations: bool = True
    evosax_options: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self):
        require_choice("es.strategy", self.strategy, (OPEN_ES, *EVOSAX_STRATEGIES))
        require_int("es.population_size", self.population_size)
        if self.population_size < 2:
            _fail("es", "population_size", self.population_size, "must be >= 2")
        if self.strategy == OPEN_ES and self.antithetic and self.population_size % 2:
            _fail("es", "population_size", self.population_size, "must be even with antithetic sampling")
        require_number("es.sigma", self.sigma, 0, low_open=True)
        require_choice("es.sigma_schedule", self.sigma_schedule, SIGMA_SCHEDULES)
        require_number("es.sigma_final", self.sigma_final, 0, low_open=True)
        if self.sigma_schedule == "constant" and self.sigma_final != ESConfig.sigma_final:
            _fail("es", "sigma_final", self.sigma_final, "is the end of a sigma_schedule: set es.sigma_schedule too")
        require_choice("es.optimizer", self.optimizer, OPTIMIZER_NAMES)
        require_number("es.learning_rate", self.learning_rate, 0, low_open=True)
        require_number("es.weight_decay", self.weight_decay, 0)
        require_choice("es.shaping", self.shaping, SHAPING_NAMES)
        require_bool("es.antithetic", self.antithetic)
        require_int("es.n_episodes", self.n_episodes)
        require_bool("es.shared_episodes", self.shared_episodes)
        require_bool("es.normalize_observations", self.normalize_observations)
        _pairs("es", "evosax_options", self.evosax_options)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """The training loop around the compiled iteration.

    Attributes:
      iterations: ES iterations in total.
      seed: the one seed every random draw descends from.
      eval_episodes: episodes on which the centre params are evaluated every iteration, on
        seeds of their own, in the same batch as the population (0: no evaluation).
      checkpoint_every: save a checkpoint every this many iterations (0: only at the end).
      iterations_per_call: iterations fused into one compiled call (host work between calls);
        ``checkpoint_every`` must be a multiple of it.
      chunk_size: the most episodes one ``vmap`` simulates together (bounds memory): a
        device's share is split into the fewest equal chunks of at most this many, which a
        ``lax.map`` runs one after another (:mod:`iap_mjx.es.rollout`).
      num_devices: devices the population is sharded over (0: all of ``jax.devices()``).
      tensorboard: also write TensorBoard event files.
      max_minutes: stop after this much wall-clock (compile included) even if fewer than
        ``iterations`` are done (0: no limit). The run's end then depends on the machine.
    """

    iterations: int = 100
    seed: int = 0
    eval_episodes: int = 8
    checkpoint_every: int = 10
    iterations_per_call: int = 1
    chunk_size: int = 64
    num_devices: int = 0
    tensorboard: bool = True
    max_minutes: float = 0.0

    def __post_init__(self):
        require_int("run.iterations", self.iterations)
        require_int("run.seed", self.seed, 0)
        require_int("run.eval_episodes", self.eval_episodes, 0)
        require_int("run.checkpoint_every", self.checkpoint_every, 0)
        require_int("run.iterations_per_call", self.iterations_per_call)
        require_int("run.chunk_size", self.chunk_size)
        require_int("run.num_devices", self.num_devices, 0)
        if self.checkpoint_every % self.iterations_per_call:
            _fail(
                "run",
                "checkpoint_every",
                self.checkpoint_every,
                f"must be a multiple of run.iterations_per_call = {self.iterations_per_call}",
            )
        require_number("run.max_minutes", self.max_minutes, 0)
        require_bool("run.tensorboard", self.tensorboard)


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything ``iap_mjx.es.train`` needs: env, policy, strategy and loop."""

    env: EnvSpec = EnvSpec()
    policy: PolicySpec = PolicySpec()
    es: ESConfig = ESConfig()
    run: RunConfig = RunConfig()

    def __post_init__(self):
        for name, cls in (("env", EnvSpec), ("policy", PolicySpec), ("es", ESConfig), ("run", RunConfig)):
            if not isinstance(getattr(self, name), cls):
                _fail("config", name, getattr(self, name), f"must be a {cls.__name__}")

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict: ``(name, value)`` pairs (env overrides, policy options, evosax
        options) become ``{name: value}`` objects in their order, tuples become lists."""
        data = dataclasses.asdict(self)
        for section, field in _PAIR_FIELDS:
            data[section][field] = {name: value for name, value in data[section][field]}
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        """The inverse of :meth:`to_dict` (also reads pairs stored as lists of lists)."""
        sections = {"env": EnvSpec, "policy": PolicySpec, "es": ESConfig, "run": RunConfig}
        unknown = set(data) - set(sections)
        if unknown:
            raise ValueError(f"unknown config sections {sorted(unknown)}; valid: {sorted(sections)}")
        pair_fields = set(_PAIR_FIELDS)

        def value(section: str, field: str, stored: Any) -> Any:
            if (section, field) in pair_fields and isinstance(stored, dict):
                stored = list(stored.items())
            return _tuplify(stored)

        return cls(
            **{
                name: section(**{k: value(name, k, v) for k, v in data.get(name, {}).items()})
                for name, section in sections.items()
            }
        )


_PAIR_FIELDS = (("env", "overrides"), ("policy", "options"), ("es", "evosax_options"))


def _tuplify(value: Any) -> Any:
    if isinstance(value, (list, tuple)):
        return tuple(_tuplify(v) for v in value)
    return value
