"""Process-level set-up: the persistent compilation cache, the number of CPU devices,
dm_control's OpenGL backend, and large constants passed as arguments.

Each must be decided before the library it concerns starts (the device count before JAX
initialises its backend, large constants and the GL backend before JAX and dm_control are
imported), so entry points (the CLI, benchmarks, ``tests/conftest.py``, the notebook) call
these first. Library code never calls them: importing ``iap_mjx`` changes no global state
(:func:`persistent_cache_off` is scoped and undone on exit).
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator
from pathlib import Path

from iap_mjx.files import write_atomically

logger = logging.getLogger(__name__)

CACHE_ENV_VAR = "IAP_MJX_CACHE_DIR"


def default_cache_dir() -> Path:
    """Where compiled programs are kept: ``$IAP_MJX_CACHE_DIR`` or ``~/.cache/iap_mjx/jax``."""
    return Path(os.environ.get(CACHE_ENV_VAR, Path.home() / ".cache" / "iap_mjx" / "jax"))


def enable_compilation_cache(cache_dir: str | os.PathLike | None = None) -> Path:
    """Turns on JAX's persistent compilation cache, so a program compiled once is reused.

    Every compiled program is cached, however quick its compile (the threshold is 0 s), since
    on a 2-core CPU even small programs add up. Entries are written whole or not at all
    (:func:`write_entries_atomically`), so processes sharing the directory (test workers, two
    trainings at once) never read one another's half-written entries. Returns the cache
    directory.
    """
    import jax

    path = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path.mkdir(parents=True, exist_ok=True)
    write_entries_atomically()
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    logger.debug("JAX persistent compilation cache at %s", path)
    return path


def write_entries_atomically() -> bool:
    """Makes JAX's file cache write each entry to a temporary file in the cache directory and
    rename it into place, so a reader sees a whole entry or none.

    JAX's ``LRUCache`` (jax 0.10) writes ``<key>-cache`` in place: another process that
    compiles the same program meanwhile finds the file, reads a truncated stream and warns
    ("Error reading persistent compilation cache entry ... incomplete or truncated stream"),
    and a process killed mid-write leaves a truncated entry behind for good. The rename is
    atomic on a local filesystem. An entry is rewritten when it is written again (JAX writes
    only after a compile, so after a miss or an unreadable entry), which also replaces a
    truncated entry left by an earlier process. With a size cap (``jax_compilation_cache_max_size``)
    JAX's own locked writes are kept. Returns whether the atomic writer is in place (False if
    this JAX's cache internals differ from what it replaces: the cache then works as JAX's).
    """
    from jax._src import compilation_cache, lru_cache

    installed = getattr(compilation_cache, "LRUCache", None)
    if getattr(installed, "writes_atomically", False):
        return True
    if installed is not lru_cache.LRUCache or not hasattr(lru_cache, "_CACHE_SUFFIX"):
        logger.warning(
            "this JAX's compilation cache is not the one iap_mjx knows; entries are "
            "written as JAX writes them (not atomically)"
        )
        return False

    class AtomicLRUCache(lru_cache.LRUCache):
        """JAX's file cache whose uncapped writes go through a temporary file and a rename."""

        writes_atomically = True

        def put(self, key: str, value: bytes) -> None:
            if self.eviction_enabled:  # JAX serialises reads and writes with a file lock
                return super().put(key, value)
            if not key:
                raise ValueError("key cannot be empty")
            write_atomically(Path(self.path) / f"{key}{lru_cache._CACHE_SUFFIX}", value)

    compilation_cache.reset_cache()  # a cache built before this call is rebuilt with the writer
    compilation_cache.LRUCache = AtomicLRUCache  # type: ignore[misc]  # JAX's class replaced on purpose
    return True


LARGE_CONSTANT_BYTES = 1 << 20


def hoist_large_constants(max_embedded_bytes: int = LARGE_CONSTANT_BYTES) -> bool:
    """Arrays larger than ``max_embedded_bytes`` that jitted code closes over become arguments
    of the compiled program instead of constants embedded in it (JAX's
    ``jax_use_simplified_jaxpr_constants``). The Distracting Control Suite's background videos
    (tens to hundreds of MB, closed over by the env) would otherwise be copied into every
    program, which then takes minutes to compile and fills the compilation cache; smaller
    constants stay embedded, where XLA can fold them.

    Takes effect only if JAX is not imported yet (the flag is read at import). Returns whether
    it is in force.
    """
    import sys

    if "jax" in sys.modules:
        import jax

        return bool(jax.config.values["jax_use_simplified_jaxpr_constants"])
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
            return int(flag[len(key) :])
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


def setup() -> Path:
    """Everything an entry point sets up before anything imports JAX or dm_control, as the CLI
    does: large constants as arguments (:func:`hoist_large_constants`), one XLA device per core
    (:func:`set_host_device_count`), the persistent compilation cache
    (:func:`enable_compilation_cache`) and no OpenGL for dm_control
    (:func:`disable_dm_control_rendering`). A script or notebook calls it first; returns the
    cache directory. Called after JAX was imported, the device count and the constants stay
    as JAX started with them, and a warning says so."""
    import sys

    late = "jax" in sys.modules
    hoisted = hoist_large_constants()
    count = set_host_device_count()
    cache_dir = enable_compilation_cache()
    disable_dm_control_rendering()
    if late:
        import jax

        if jax.device_count() != count or not hoisted:
            logger.warning(
                "runtime.setup() ran after JAX was imported: %d XLA device(s) instead of %d, large constants "
                "%s; call it before anything imports jax",
                jax.device_count(),
                count,
                "passed as arguments" if hoisted else "embedded in every program",
            )
    return cache_dir


@contextlib.contextmanager
def persistent_cache_off() -> Iterator[None]:
    """Within the block JAX compiles every program and neither reads nor writes the
    persistent cache; on exit the cache is as it was.

    For timings that report compile seconds (Figure 8's ``measure``): with the cache on, a
    program compiled by an earlier run loads in a fraction of its compile time, and which
    variants had been compiled before would decide their reported compile seconds. This is the
    one scoped change of process state that library code makes, undone on exit.
    """
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    enabled = jax.config.values["jax_enable_compilation_cache"]
    jax.config.update("jax_enable_compilation_cache", False)
    compilation_cache.reset_cache()  # JAX decides once per process whether the cache is used
    try:
        yield
    finally:
        jax.config.update("jax_enable_compilation_cache", enabled)
        compilation_cache.reset_cache()
