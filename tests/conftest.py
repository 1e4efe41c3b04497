"""Test-session set-up: the persistent compilation cache, two XLA CPU devices, a quicker XLA
backend, and the slow tests scheduled first.

Two devices let the sharding tests run (``--xla_force_host_platform_device_count=2`` must be
set before JAX starts, hence here); single-device code is unaffected.

Most of the suite's time is XLA compiling MJX programs that then run for a fraction of a
second, so the tests ask LLVM for no optimisation (``--xla_backend_optimization_level=0``):
the same HLO, compiled about a fifth faster, running slower where it hardly matters; and
XLA:CPU's older loop emitters instead of its MLIR fusion emitters
(``--xla_cpu_use_fusion_emitters=false``), which cut the CPU time of compiling the first-run
ES iteration from 35.9 s to 26.6 s. Child processes (the CLI and notebook tests) inherit both
through ``XLA_FLAGS``. Timed figures come from ``benchmarks/``, never from here.

Programs are partitioned by GSPMD rather than Shardy, JAX's default
(``JAX_USE_SHARDY_PARTITIONER=false``, inherited by child processes): Shardy's propagation is
a large share of XLA's time on our programs, whose one partitioning is the ``shard_map`` over
the population. The README's command (``test_first_run``) and the notebook, run as a user runs
them, keep JAX's default, so Shardy is tested there. The variable is set before JAX starts:
``jax.config.update`` after the import left a vmapped render 3.5e-5 away from the same render
unbatched (``test_render_batching``, reproducibly; under either partitioner set at the start
it is within 1e-5). A parent and the children whose results it compares bit for bit (a run
killed in a child and resumed here) use the same partitioner: the two round a few operations
differently.

Tests marked ``slow`` (a minute or more: end-to-end runs, multi-task parity) are handed out
first, so that no long test starts last and keeps one worker busy after the other is done;
tests marked ``last`` go at the end (they reuse an earlier test's compiled programs).
"""

import os
from pathlib import Path

from iap_mjx import runtime

os.environ.setdefault("JAX_USE_SHARDY_PARTITIONER", "false")  # before JAX reads its config: see above
_FAST_COMPILE = {"--xla_backend_optimization_level": "0", "--xla_cpu_use_fusion_emitters": "false"}
for _flag, _value in _FAST_COMPILE.items():
    if _flag not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_flag}={_value}".strip()
runtime.hoist_large_constants()  # as the CLI: large closed-over arrays are arguments
runtime.set_host_device_count(2)
runtime.disable_dm_control_rendering()  # reference renders run in child processes
runtime.enable_compilation_cache(Path(__file__).resolve().parent.parent / ".jax_cache")


def pytest_collection_modifyitems(items):
    """Slow tests first, tests marked ``last`` at the end (a stable sort: the order within each
    group is kept). A ``last`` test compiles what an earlier test compiled (the same shapes), so
    it loads the programs from the shared compilation cache instead."""
    items.sort(key=lambda item: (item.get_closest_marker("last") is not None, item.get_closest_marker("slow") is None))
