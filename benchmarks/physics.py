"""Physics throughput of the MJX task ports next to native MuJoCo, and the solver sweep.

Two suites, one command line; each writes its own section of ``BENCHMARKS.md`` from the same
parts, measured the same way:

- the dm_control task ports (default; section ``physics``), against dm_control itself;
- ``--quadruped``: our A1-class quadruped (``quadruped-flat``, ``quadruped-walls``; section
  ``physics-quadruped``), against native MuJoCo (``mujoco.mj_step``/``mujoco.rollout``,
  float64) on the env's own compiled model (there is no dm_control task).

This file is the command line: each suite's tasks and defaults (``DM_CONTROL``,
``QUADRUPED``), which parts are measured and saved, and the section written. What is measured
lives in ``physics_parts.py``, the sections' text in ``physics_sections.py``.

The parts (``--parts``; each suite's default is all of its own):

1. ``sweep``, solver settings: for each task in ``--sweep-tasks`` and each ``--sweep`` setting
   (``physics_parts.parse_setting``), the qpos error over ``--sweep-steps`` control steps against the
   suite's reference (dm_control: float64, Newton, 100 iterations, from dm_control's own
   start, half uniform and half saturated actions, median over 3 seeds; the quadruped: native
   on the same model and native converged at MuJoCo's defaults, 3 episodes of PD targets
   around the standing pose), next to native MuJoCo's own sensitivity (restarted 1 float32
   ulp off), and the env-steps/s at B=256 on all devices.
2. ``throughput``: env-steps/s (control steps x envs / s, steady state) per task at each B in
   ``--batch``, on one XLA device and on all (``shard_map``), next to ``mujoco.rollout`` with
   1 and 2 threads on the native model running the same number of physics steps from the
   same states, measured in the same run; compile time separately.
3. ``camera`` (the quadruped only): the first-person camera's frames/s at each
   ``--camera-batch``.
4. ``long``: a full population: ``--long-batch`` envs x a full episode in one chunked,
   sharded call per task in ``--long-tasks``, with its wall-clock and how many envs ended.

Each part measured saves its rows to ``--rows-dir`` (``benchmarks/physics-dm_control/`` or
``benchmarks/physics-quadruped/``, ``<part>.json`` with its command, time, ``XLA_FLAGS`` and
load), and the section is written from every part saved there, so the parts can be measured
one per command, each in a shorter hold of the machine. Run (heavy; serialise with the other
benchmarks):

    python benchmarks/physics.py                                   # every dm_control part
    python benchmarks/physics.py --quadruped --parts sweep --no-write
    ...
    python benchmarks/physics.py --quadruped --parts               # no measuring: writes the section

Envs are vmapped in chunks of ``--chunk-size`` per device (default 256; the quadruped 32, the
size its ``BENCHMARKS.md`` rows record), at most each env's ``max_chunk_size``: with jaxlib
0.10 a larger vmapped batch sharded over two devices deadlocks XLA:CPU at its first execution
(the intra-op pool threads each block in a batched LAPACK Cholesky waiting for tasks queued on
that same pool; ``iap_mjx.envs.dmc.serial_lapack_batch``, and the physics-quadruped section of
``BENCHMARKS.md``). ``--xla_cpu_multi_thread_eigen=false`` does not avoid it (the LAPACK kernels
use XLA's intra-op pool, not Eigen's) and is not set.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

from iap_mjx import runtime

DEVICE_COUNT = runtime.set_host_device_count(2)

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import physics_parts  # noqa: E402
import physics_sections  # noqa: E402
import report  # noqa: E402
from physics_parts import QUADRUPED_TASKS, TASKS  # noqa: E402

from iap_mjx import envs  # noqa: E402

PARTS = ("sweep", "throughput", "camera", "long")


@dataclasses.dataclass(frozen=True)
class Suite:
    """One benchmark's tasks, defaults, parts and section."""

    section: str
    rows_dir: Path
    parts: tuple[str, ...]
    tasks: tuple[str, ...]
    sweep_tasks: tuple[str, ...]
    sweep: tuple[str, ...]
    long_tasks: tuple[str, ...]
    chunk_size: int
    markdown: Callable[[dict[str, list[dict]], argparse.Namespace], str]


DM_CONTROL = Suite(
    section="physics",
    rows_dir=ROOT / "benchmarks" / "physics-dm_control",
    parts=("sweep", "throughput", "long"),
    tasks=TASKS,
    sweep_tasks=("cheetah-run", "walker-walk"),
    sweep=("8/8/all", "8/8/task", "4/4/task", "8/2/task", "16/2/task"),
    long_tasks=("cheetah-run",),
    chunk_size=256,
    markdown=physics_sections.dm_control_markdown,
)
QUADRUPED = Suite(
    section="physics-quadruped",
    rows_dir=ROOT / "benchmarks" / "physics-quadruped",
    parts=PARTS,
    tasks=QUADRUPED_TASKS,
    sweep_tasks=("quadruped-walls",),
    sweep=(
        "newton/1/4",
        "newton/2/4",
        "newton/4/4",
        "newton/8/2",
        "newton/8/4",
        "newton/8/8",
        "newton/100/50",
        "cg/8/4",
        "cg/16/4",
        "cg/100/50",
    ),
    long_tasks=("quadruped-walls",),
    chunk_size=32,
    markdown=physics_sections.quadruped_markdown,
)


def measure(part: str, args) -> list[dict]:
    """The rows of one part, with the settings in ``args``."""
    if part == "sweep":
        return [
            row
            for name in args.sweep_tasks
            for row in physics_parts.solver_sweep(name, args.sweep, args.sweep_steps, args.repeats, args.chunk_size)
        ]
    if part == "throughput":
        return [
            row
            for name in args.tasks
            for row in physics_parts.throughput(name, args.batch, args.steps, args.chunk_size, args.repeats)
        ]
    if part == "camera":
        return physics_parts.camera_rate("quadruped-walls", args.camera_batch, args.repeats, args.chunk_size)
    if part == "long":
        return [physics_parts.long_run(name, args.long_batch, args.chunk_size) for name in args.long_tasks]
    raise ValueError(f"unknown part {part!r}")


def run(suite: Suite, args) -> str:
    """Measures ``args.parts``, saving each part's rows (with the command and load that produced
    them) in ``args.rows_dir``, and returns the section written from every part saved there."""
    rows_dir = Path(args.rows_dir)
    rows_dir.mkdir(parents=True, exist_ok=True)
    for part in args.parts:
        load_before = os.getloadavg()[0]
        rows = measure(part, args)
        record = dict(
            argv=args.argv,
            xla_flags=os.environ.get("XLA_FLAGS", ""),
            chunk_size=args.chunk_size,
            load_before=load_before,
            load_after=os.getloadavg()[0],
            when=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            rows=rows,
        )
        (rows_dir / f"{part}.json").write_text(json.dumps(record, indent=1, default=float))
    saved = {
        part: json.loads((rows_dir / f"{part}.json").read_text())
        for part in suite.parts
        if (rows_dir / f"{part}.json").exists()
    }
    args.runs = {part: {k: v for k, v in record.items() if k != "rows"} for part, record in saved.items()}
    return suite.markdown({part: saved[part]["rows"] if part in saved else [] for part in suite.parts}, args)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quadruped",
        action="store_true",
        help="the quadruped tasks, their sweep and camera: section physics-quadruped",
    )
    parser.add_argument("--tasks", nargs="+", default=None, choices=TASKS + QUADRUPED_TASKS)
    parser.add_argument("--batch", nargs="+", type=int, default=[64, 256, 1024])
    parser.add_argument("--steps", type=int, default=20, help="control steps per timed call")
    parser.add_argument(
        "--chunk-size",
        type=int,
        default=None,
        help="envs vmapped together per device (default 256; --quadruped: 32), at most each env's max_chunk_size",
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sweep-tasks", nargs="*", default=None, choices=TASKS + QUADRUPED_TASKS)
    parser.add_argument(
        "--sweep",
        nargs="*",
        default=None,
        help="solver settings ITERATIONS/LS_ITERATIONS/CONTACTS to compare "
        "(quadruped: [SOLVER/]ITERATIONS/LS_ITERATIONS[/CONTACTS/GEOM_PAIRS])",
    )
    parser.add_argument(
        "--long-tasks",
        nargs="*",
        default=None,
        choices=TASKS + QUADRUPED_TASKS,
        help="tasks for the B=--long-batch full-episode run",
    )
    parser.add_argument(
        "--camera-batch",
        nargs="*",
        type=int,
        default=[1, 256],
        help="quadruped: batches for the first-person camera's frames/s",
    )
    parser.add_argument("--long-batch", type=int, default=1024)
    parser.add_argument("--sweep-steps", type=int, default=100)
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument(
        "--parts",
        nargs="*",
        default=None,
        choices=PARTS,
        help="the parts to measure now (default: all of the suite's; the section shows every part saved)",
    )
    parser.add_argument(
        "--rows-dir",
        default=None,
        help="where each part's rows are saved as <part>.json (default: "
        "benchmarks/physics-dm_control or, --quadruped, benchmarks/physics-quadruped)",
    )
    args = parser.parse_args(argv)
    args.argv = " ".join(argv) if argv else ""
    suite = QUADRUPED if args.quadruped else DM_CONTROL
    args.parts = list(suite.parts) if args.parts is None else args.parts
    if not set(args.parts) <= set(suite.parts):
        parser.error(f"--parts: this suite measures {', '.join(suite.parts)}")
    args.rows_dir = args.rows_dir or str(suite.rows_dir)
    args.chunk_size = args.chunk_size or suite.chunk_size
    args.tasks = args.tasks or list(suite.tasks)
    args.sweep_tasks = list(suite.sweep_tasks) if args.sweep_tasks is None else args.sweep_tasks
    args.sweep = args.sweep or list(suite.sweep)
    args.long_tasks = list(suite.long_tasks) if args.long_tasks is None else args.long_tasks
    if args.parts:
        measured = {
            "sweep": args.sweep_tasks,
            "throughput": args.tasks,
            "camera": ["quadruped-walls"],
            "long": args.long_tasks,
        }
        for name in dict.fromkeys(name for part in args.parts for name in measured[part]):
            limit = envs.make(name).max_chunk_size
            if limit is not None and args.chunk_size > limit:
                parser.error(
                    f"--chunk-size {args.chunk_size}: {name} vmaps at most {limit} envs per device "
                    "(a larger batch deadlocks XLA:CPU; see iap_mjx.envs.dmc.serial_lapack_batch)"
                )
    text = run(suite, args)
    print(text)
    if not args.no_write:
        report.write_section(ROOT / "BENCHMARKS.md", suite.section, text)


if __name__ == "__main__":
    main(sys.argv[1:])
