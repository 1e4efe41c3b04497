"""iap-mjx: Implicit Attention for Pixels on MJX, trained with evolution strategies on a CPU.

Layers, lowest first (a lower layer never imports a higher one):
``configs`` (frozen configuration dataclasses and the preset table: plain data), ``chunks`` and
``loops`` (a batch as a loop over chunks; loop carries batched before the loop: jax only) ->
``attention`` (feature maps, patches, scores), ``render`` (ray-cast camera) and ``robots`` (the
quadruped's MJCF) -> ``envs`` (MJX ports of dm_control tasks, the quadruped's courses) ->
``policies`` -> ``es`` (training) -> ``viz`` (videos, strips, curves) -> ``paper`` (one module
per figure or table) -> ``cli``. ``runtime`` is process set-up that entry points (the CLI, the
tests, benchmarks, the notebook) call before JAX starts; library code calls none of it but
the scoped ``persistent_cache_off``. ``configs`` load no JAX, so a config can be built before
``runtime`` sets the process up.

The one-call entry points are here too: ``iap_mjx.train(config)``, ``iap_mjx.load_run(run_dir)``
and ``iap_mjx.evaluate_run(run_dir, ...)`` are :mod:`iap_mjx.es`'s, imported on first use, so
that ``import iap_mjx`` (and ``from iap_mjx import runtime``) loads no JAX.
"""

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # their types, for type checkers; at run time __getattr__ imports them
    from iap_mjx.es.results import evaluate_run as evaluate_run
    from iap_mjx.es.results import load_run as load_run
    from iap_mjx.es.train import train as train

__version__ = "0.1.0"

_FROM_ES = ("train", "load_run", "evaluate_run")


def __getattr__(name: str) -> Any:
    if name in _FROM_ES:
        from iap_mjx import es

        return getattr(es, name)
    raise AttributeError(f"module 'iap_mjx' has no attribute {name!r}")
