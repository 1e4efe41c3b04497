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
"""

__version__ = "0.1.0"
