"""Shared by the benchmark scripts: timing with compile time apart, and BENCHMARKS.md sections."""

from __future__ import annotations

import platform
import shlex
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent

from iap_mjx.sections import write_section  # noqa: E402,F401  (the benchmarks' sections)


def readme_main_command() -> list[str]:
    """The arguments after ``iap-mjx`` of the README's install-and-train line (the main job).

    Shared by ``first_run.py`` and ``tests/test_first_run.py``, so both run what the README says.
    """
    for line in (ROOT / "README.md").read_text().splitlines():
        if "iap-mjx train" in line and "pip install" in line:
            return shlex.split(line.split("&& iap-mjx ", 1)[1])
    raise ValueError("README.md has no install-and-train line (`pip install ... && iap-mjx train ...`)")


def compile_and_time(fn: Callable, *args: Any, repeats: int = 5, min_seconds: float = 0.5) -> tuple[float, float, Any]:
    """Compiles ``jax.jit(fn)`` for ``args`` and times it.

    Returns ``(compile_seconds, steady_seconds_per_call, compiled)``: compile time is lowering
    plus XLA compilation; the steady-state time is the median over ``repeats`` timed batches of
    calls (each batch at least ``min_seconds`` long), after one warm-up call.
    """
    import jax

    start = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_seconds = time.perf_counter() - start
    times = interleaved_times([compiled], [args], rounds=repeats, min_seconds=min_seconds)
    return compile_seconds, statistics.median(row[0] for row in times), compiled


def interleaved_times(
    compiled: Sequence[Callable], args: Sequence[tuple], *, rounds: int = 9, min_seconds: float = 0.3
) -> list[list[float]]:
    """Steady-state seconds per call of several compiled programs, timed in turns.

    Each round times every program once (a batch of calls at least ``min_seconds`` long), so
    a change in the machine's load hits all of them alike; ratios are then taken per round.
    Returns ``times[round][program]``.
    """
    import jax

    calls = []
    for fn, fn_args in zip(compiled, args):
        jax.block_until_ready(fn(*fn_args))
        once = time.perf_counter()
        jax.block_until_ready(fn(*fn_args))
        calls.append(max(1, int(min_seconds / max(time.perf_counter() - once, 1e-6))))
    times = []
    for _ in range(rounds):
        row = []
        for fn, fn_args, count in zip(compiled, args, calls):
            start = time.perf_counter()
            for _ in range(count):
                out = fn(*fn_args)
            jax.block_until_ready(out)
            row.append((time.perf_counter() - start) / count)
        times.append(row)
    return times


def machine_line() -> str:
    """One line naming the machine and the JAX set-up a table was measured on."""
    import os

    import jax

    return (
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"jax {jax.__version__}, {len(jax.devices())} XLA CPU device(s)"
    )
