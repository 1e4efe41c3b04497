"""Test-session set-up: the persistent compilation cache, and two XLA CPU devices.

Two devices let the sharding tests run (``--xla_force_host_platform_device_count=2`` must be
set before JAX starts, hence here); single-device code is unaffected.
"""

from pathlib import Path

from iap_mjx import runtime

runtime.set_host_device_count(2)
runtime.disable_dm_control_rendering()  # reference renders run in child processes
runtime.enable_compilation_cache(
    Path(__file__).resolve().parent.parent / ".jax_cache"
)
