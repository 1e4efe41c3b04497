"""Process set-up: the persistent compilation cache's entries are written whole.

Test workers share ``.jax_cache/`` and users may run two trainings on one cache directory; JAX's
own cache writes ``<key>-cache`` in place, so a process reading it meanwhile gets a truncated
stream. Below, a write is held halfway while the entry is read: JAX's own ``LRUCache`` hands out
half an entry, the writer ``runtime.enable_compilation_cache`` installs hands out none.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import jax
import jax.numpy as jnp
from jax._src import compilation_cache, lru_cache

from iap_mjx import runtime

VALUE = bytes(range(256)) * 64


class _HeldWrite(io.RawIOBase):
    """A binary file whose ``write`` writes the first half, signals ``halfway``, waits for
    ``release`` and writes the rest."""

    def __init__(self, file, halfway: threading.Event, release: threading.Event):
        self.file, self.halfway, self.release = file, halfway, release

    def write(self, value) -> int:
        half = len(value) // 2
        self.file.write(value[:half])
        self.file.flush()
        self.halfway.set()
        self.release.wait()
        self.file.write(value[half:])
        return len(value)

    def close(self) -> None:
        self.file.close()
        super().close()


def _read_while_half_written(cache, halfway: threading.Event, release: threading.Event):
    """``cache.put("entry", VALUE)`` in a thread, held halfway (the test patches the file
    write to hold): what ``cache.get("entry")`` returns then, and after the write."""
    writer = threading.Thread(target=cache.put, args=("entry", VALUE))
    writer.start()
    while not halfway.wait(0.05):  # a poll, not a time limit
        assert writer.is_alive(), "the write went past the patched file write"
    during = cache.get("entry")
    release.set()
    writer.join()
    return during, cache.get("entry")


def test_a_reader_never_sees_a_half_written_entry(tmp_path, monkeypatch):
    """The writer ``enable_compilation_cache`` installs: a read during the write finds no
    entry, a read after it the whole one."""
    assert runtime.write_entries_atomically()
    atomic = compilation_cache.LRUCache
    assert atomic is not lru_cache.LRUCache and issubclass(atomic, lru_cache.LRUCache)
    halfway, release = threading.Event(), threading.Event()
    fdopen = os.fdopen
    monkeypatch.setattr(os, "fdopen", lambda fd, mode: _HeldWrite(fdopen(fd, mode), halfway, release))
    during, after = _read_while_half_written(atomic(str(tmp_path), max_size=-1), halfway, release)
    assert during is None and after == VALUE
    assert [p.name for p in tmp_path.iterdir()] == ["entry-cache"]  # no temporary file left


def test_jax_s_own_cache_hands_out_a_half_written_entry(tmp_path, monkeypatch):
    """The failure the writer prevents, seen by the same check: JAX's ``LRUCache`` writes in
    place (``Path.write_bytes``), so the read during the write gets half the entry."""
    halfway, release = threading.Event(), threading.Event()

    def write_bytes(path, data: bytes) -> int:
        with _HeldWrite(open(path, "wb"), halfway, release) as f:
            return f.write(data)

    cache = lru_cache.LRUCache(str(tmp_path), max_size=-1)
    monkeypatch.setattr(type(cache.path), "write_bytes", write_bytes)
    during, after = _read_while_half_written(cache, halfway, release)
    assert during == VALUE[: len(VALUE) // 2] and after == VALUE


def test_jax_writes_its_entries_through_the_atomic_writer(tmp_path):
    """A fresh interpreter set up as the CLI is compiles a program: JAX's cache is the atomic
    one, the entry lands under JAX's name, no temporary file is left, and a second process
    loads it instead of compiling."""
    script = textwrap.dedent(f"""
        import json, sys
        from iap_mjx import runtime
        runtime.enable_compilation_cache({str(tmp_path)!r})
        import jax, jax.numpy as jnp
        from jax._src import compilation_cache
        out = jax.jit(lambda x: jnp.sin(x) * 3.0 + x)(jnp.arange(5.0))
        cache = compilation_cache._get_cache(jax.devices()[0].client)
        print(json.dumps({{"atomic": getattr(type(cache), "writes_atomically", False),
                           "value": float(out.sum())}}))
    """)

    def run() -> str:
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
        assert '"atomic": true' in done.stdout.splitlines()[-1], done.stdout + done.stderr
        assert "Error reading persistent compilation cache" not in done.stderr
        return done.stdout

    def entries() -> dict[str, int]:
        return {p.name: p.stat().st_mtime_ns for p in tmp_path.iterdir()}

    first = run()
    written = entries()
    assert written and all(name.endswith("-cache") for name in written), written
    assert run() == first
    assert entries() == written  # the second process loaded every program: nothing rewritten


def test_a_truncated_entry_is_replaced_when_written_again(tmp_path):
    """An entry truncated by a process killed mid-write (before this writer) is replaced by the
    next write of the same key, where JAX's cache keeps it forever."""
    assert runtime.write_entries_atomically()
    cache = compilation_cache.LRUCache(str(tmp_path), max_size=-1)
    (tmp_path / "k-cache").write_bytes(b"trunc")
    cache.put("k", b"whole entry")
    assert cache.get("k") == b"whole entry"
    jax_cache = lru_cache.LRUCache(str(tmp_path), max_size=-1)
    (tmp_path / "j-cache").write_bytes(b"trunc")
    jax_cache.put("j", b"whole entry")
    assert jax_cache.get("j") == b"trunc"  # why the writer replaces entries


def test_the_suites_own_cache_writes_atomically():
    """The cache this test worker's JAX uses (set up by conftest through
    ``enable_compilation_cache``, as the CLI does) is the atomic writer, on ``.jax_cache/``."""
    jax.jit(lambda v: jnp.cumsum(v * v))(jnp.linspace(0.0, 1.0, 7)).block_until_ready()  # the cache is built lazily
    cache = compilation_cache._get_cache(jax.devices()[0].client)
    assert getattr(type(cache), "writes_atomically", False), type(cache)
    assert Path(str(cache.path)).resolve() == Path(__file__).resolve().parent.parent / ".jax_cache"


def test_persistent_cache_off_compiles_without_the_cache_and_restores_it(tmp_path):
    """In a fresh interpreter with the cache on: a program compiled inside
    ``persistent_cache_off`` writes no entry, one compiled after it does, and the setting is
    restored."""
    script = textwrap.dedent(f"""
        import json
        from pathlib import Path
        from iap_mjx import runtime
        runtime.enable_compilation_cache({str(tmp_path)!r})
        import jax, jax.numpy as jnp
        jax.jit(lambda x: x * 2.0)(jnp.ones(3)).block_until_ready()  # the cache is built lazily
        before = len(list(Path({str(tmp_path)!r}).iterdir()))
        with runtime.persistent_cache_off():
            jax.jit(lambda x: jnp.cos(x) - 5.0)(jnp.ones(4)).block_until_ready()
        inside = len(list(Path({str(tmp_path)!r}).iterdir()))
        jax.jit(lambda x: jnp.tanh(x) + 7.0)(jnp.ones(6)).block_until_ready()
        after = len(list(Path({str(tmp_path)!r}).iterdir()))
        print(json.dumps({{"before": before, "inside": inside, "after": after,
                           "enabled": bool(jax.config.jax_enable_compilation_cache)}}))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    counts = json.loads(done.stdout.splitlines()[-1])
    assert counts["before"] >= 1, counts
    assert counts["inside"] == counts["before"], counts
    assert counts["after"] > counts["inside"], counts
    assert counts["enabled"], counts


def test_setup_does_what_the_cli_does_before_jax_starts(tmp_path):
    """``runtime.setup()`` first in a fresh interpreter (as a script or the notebook calls it):
    one XLA device per core, the cache directory in force, large constants as arguments,
    dm_control without OpenGL; with the environment clean of the tests' own settings."""
    script = textwrap.dedent("""
        import json, os
        from iap_mjx import runtime
        cache_dir = runtime.setup()
        import jax
        print(json.dumps({"devices": jax.device_count(), "cores": os.cpu_count(), "cache": str(cache_dir),
                          "jax_cache": jax.config.jax_compilation_cache_dir,
                          "hoisted": bool(jax.config.jax_use_simplified_jaxpr_constants),
                          "gl": os.environ.get("MUJOCO_GL")}))
    """)
    environment = {
        key: value
        for key, value in os.environ.items()
        if key not in ("XLA_FLAGS", "MUJOCO_GL", "JAX_USE_SIMPLIFIED_JAXPR_CONSTANTS", "JAX_COMPILATION_CACHE_DIR")
    }
    environment[runtime.CACHE_ENV_VAR] = str(tmp_path)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, env=environment)
    state = json.loads(done.stdout.splitlines()[-1])
    assert state["devices"] == state["cores"], state
    assert state["cache"] == state["jax_cache"] == str(tmp_path), state
    assert state["hoisted"] and state["gl"] == "disable", state
    assert "after JAX was imported" not in done.stderr

    # too late: JAX started first, with one device and embedded constants, and setup says so
    late = "import jax; jax.devices()\n" + script
    done = subprocess.run([sys.executable, "-c", late], capture_output=True, text=True, check=True, env=environment)
    assert json.loads(done.stdout.splitlines()[-1])["devices"] == 1
    assert "runtime.setup() ran after JAX was imported: 1 XLA device(s)" in done.stderr, done.stderr
