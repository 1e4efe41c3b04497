"""Process-level set-up: the persistent compilation cache, the number of CPU devices,
dm_control's OpenGL backend, and large constants passed as arguments.

Each must be decided before the library it concerns starts (the device count before JAX
initialises its backend, large constants and the GL backend before JAX and dm_control are
imported), so entry points (the CLI, benchmarks, ``tests/conftest.py``, the notebook) call
these first. Library code never calls them: importing ``iap_mjx`` changes no global state.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

logger = logging.getLogger(__name__)

CACHE_ENV_VAR = "IAP_MJX_CACHE_DIR"


def default_cache_dir() -> Path:
    """Where compiled programs are kept: ``$IAP_MJX_CACHE_DIR`` or ``~/.cache/iap_mjx/jax``."""
    return Path(os.environ.get(CACHE_ENV_VAR, Path.home() / ".cache" / "iap_mjx" / "jax"))


def enable_compilation_cache(cache_dir: str | os.PathLike | None = None) -> Path:
    """Turns on JAX's persistent compilation cache, so a program compiled once is reused.

    Every compiled program is cached, however quick its compile (the threshold is 0 s), since
    on a 2-core CPU even small programs add up. Returns the cache directory.
    """
    import jax

    path = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    logger.debug("JAX persistent compilation cache at %s", path)
    return path


LARGE_CONSTANT_BYTES = 1 << 20


def hoist_large_constants(max_embedded_bytes: int = LARGE_CONSTANT_BYTES) -> bool:
    """Arrays larger than ``max_embedded_bytes`` that jitted code closes over become arguments
    of the compiled program instead of constants embedded in it (JAX's
    ``jax_use_simplified_jaxpr_constants``). The Distracting Control Suite's background videos
    (tens to hundreds of MB, closed over by the env) would otherwise be copied into every
    program, which then takes minutes to compile and fills the compilation cache; smaller
    constants stay embedded as before.

    Takes effect only if JAX is not imported yet (the flag is read at import). Returns whether
    it is in force.
    """
    import sys

    if "jax" in sys.modules:
        import jax

        return bool(jax.config.jax_use_simplified_jaxpr_constants)
    os.environ.setdefault("JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS", "1")
    os.environ.setdefault("JAX_EMBEDDED_CONSTANTS_MAX_BYTES", str(int(max_embedded_bytes)))
    return os.environ["JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS"].lower() in ("1", "true")


def set_host_device_count(count: int | None = None) -> int:
    """Splits the CPU into ``count`` XLA devices (default: one per core) for sharding.

    Must run before JAX initialises its backend; an existing
    ``--xla_force_host_platform_device_count`` in ``XLA_FLAGS`` is left as it is.
    Returns the count that is in force.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    key = "--xla_force_host_platform_device_count="
    for flag in flags.split():
        if flag.startswith(key):
            return int(flag[len(key):])
    count = count if count is not None else (os.cpu_count() or 1)
    os.environ["XLA_FLAGS"] = f"{flags} {key}{count}".strip()
    return count


def disable_dm_control_rendering() -> str:
    """Tells dm_control, before it is imported, that this process renders nothing with OpenGL.

    We use dm_control for its models and as a reference, and draw every image with our own
    camera; MuJoCo's renderer, where a test or benchmark compares against it, runs in a child
    process that chooses its own backend. Left unset, importing ``dm_control.suite`` probes
    GLFW first, which on a machine without a screen prints an X11 error. An existing
    ``MUJOCO_GL`` is left as it is. Returns the value in force.
    """
    return os.environ.setdefault("MUJOCO_GL", "disable")
