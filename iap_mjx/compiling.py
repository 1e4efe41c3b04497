"""Lowering a program so that the persistent compilation cache finds it in any process:
``lower_afresh(jitted, *args)``.

JAX keys its persistent cache on a hash of the lowered module, and the module depends on what
the process traced before: jitted helpers (``jnp.where``, ``jnp.clip``, ``jnp.take``...) that an
earlier trace cached are lowered as one shared function where a first trace emits one per call
site, and the functions' names carry counters. The compiled program computes the same either
way (XLA's optimised HLO is equal up to instruction names), but its key is not: a program lowered
after other work in the same process (a report's second run or evaluation, a run after another
in ``reproduce``), or while another thread traces (the CLI compiles the run's video beside its
training call), misses the entry an earlier process wrote and compiles again. Lowered one at a
time on cleared caches, every program's module is the one a fresh process makes.
"""

from __future__ import annotations

import threading
from typing import Any

import jax

# JAX's trace caches are the process's, so the lock that keeps two lowerings from filling them
# at once is the process's too
_LOWERING = threading.Lock()


def lower_afresh(jitted: Any, *args: Any) -> Any:
    """``jitted.lower(*args)`` on cleared JAX caches (``jax.clear_caches()``), one lowering at a
    time in the process, so that the lowered module, and with it the persistent cache's key, is
    the same whatever the process traced before or traces beside it. ``jitted``: a
    ``jax.jit``-wrapped function; compile the result (``.compile()``) outside, where two
    programs may compile at once. Functions jitted earlier in the process trace again on their
    next call."""
    with _LOWERING:
        jax.clear_caches()
        return jitted.lower(*args)
