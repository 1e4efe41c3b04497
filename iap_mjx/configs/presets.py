"""Named presets: ``get(name) -> TrainConfig``, ``names()``, ``describe(name)``.

A preset is a function returning a ``TrainConfig``; ``register`` adds one (later issues add
the pixel presets the same way).
"""

from __future__ import annotations

from typing import Callable

from iap_mjx.es.config import EnvConfig, ESConfig, PolicyConfig, RunConfig, TrainConfig

_PRESETS: dict[str, tuple[str, Callable[[], TrainConfig]]] = {}


def register(name: str, description: str, make: Callable[[], TrainConfig]) -> None:
    """Adds preset ``name``; ``make()`` builds its config."""
    _PRESETS[name] = (description, make)


def names() -> list[str]:
    """All preset names, sorted."""
    return sorted(_PRESETS)


def describe(name: str) -> str:
    """The preset's one-line description."""
    return _lookup(name)[0]


def get(name: str) -> TrainConfig:
    """The preset's config; an unknown name raises ``ValueError`` listing the valid ones."""
    return _lookup(name)[1]()


def _lookup(name: str) -> tuple[str, Callable[[], TrainConfig]]:
    if name not in _PRESETS:
        raise ValueError(f"unknown preset {name!r}; valid presets: {', '.join(names())}")
    return _PRESETS[name]


register(
    "cheetah-run-state",
    "cheetah-run from the 17-d state, linear policy, OpenES (the sanity bar: >= 400 in 15 min)",
    lambda: TrainConfig(
        env=EnvConfig("cheetah-run"),
        policy=PolicyConfig("linear"),
        es=ESConfig(population_size=64, sigma=0.03, learning_rate=0.02, weight_decay=0.005,
                    n_episodes=1, normalize_observations=True),
        run=RunConfig(iterations=200, eval_episodes=8, checkpoint_every=10),
    ),
)
register(
    "cheetah-run-state-mlp",
    "cheetah-run from the 17-d state, MLP (32, 32) policy, OpenES",
    lambda: TrainConfig(
        env=EnvConfig("cheetah-run"),
        policy=PolicyConfig("mlp", (("hidden_sizes", (32, 32)),)),
        es=ESConfig(population_size=256, sigma=0.02, learning_rate=0.01, weight_decay=0.005,
                    n_episodes=1, normalize_observations=True),
        run=RunConfig(iterations=400, eval_episodes=8, checkpoint_every=10),
    ),
)
register(
    "cheetah-run-state-cmaes",
    "cheetah-run from the state, linear policy, CMA-ES through the evosax adapter",
    lambda: TrainConfig(
        env=EnvConfig("cheetah-run"),
        policy=PolicyConfig("linear"),
        es=ESConfig(strategy="CMA_ES", population_size=64, sigma=0.1, antithetic=False,
                    normalize_observations=True),
        run=RunConfig(iterations=400, eval_episodes=8, checkpoint_every=10),
    ),
)
