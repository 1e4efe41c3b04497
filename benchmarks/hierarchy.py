"""The hierarchical quadruped policies' cost on the course next to the PMTG low level alone
(issue 24): seconds per ES iteration, env steps/s and compile time of the whole program.

Every program is ``iap_mjx.es.train`` for a few iterations of a preset (population 64, the
presets' own episode lengths and evaluation episodes), each in its own Python process, one
after another:

- the PMTG low level alone, as trained on the flat (``quadruped-flat-pmtg``, 10 s episodes);
- the PMTG low level alone on the course (the same preset with ``env.name=quadruped-walls``:
  20 s episodes, walls and their contacts, no camera): the baseline of the ratios;
- the hierarchical policies (``quadruped-walls-iap``, ``-cnn``, ``-blind``): the camera
  (24x32), the high level every step, the latent held, the low level.

With ``--course gates`` the same on the gates corridor (``quadruped-gates``, beyond the paper): the
low level alone on the corridor is the baseline, beside ``quadruped-gates-iap`` (depth patches) and
``quadruped-gates-blind``; it writes the ``hierarchy-gates`` section.

Steady state is the median over the iterations after the first; compile is the first
iteration's, with the persistent compilation cache off (every program compiled). Ratios are
taken between programs of the same run.

    python benchmarks/hierarchy.py                 # ~10 min; writes the hierarchy section of BENCHMARKS.md
    python benchmarks/hierarchy.py --course gates  # ~7 min; the hierarchy-gates section
    python benchmarks/hierarchy.py --no-write      # print only
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import report  # noqa: E402

BASELINE = "low level alone, course"
# per course: its BENCHMARKS.md section, its heading's name for it, and (label, preset, overrides)
# of every program; the one labelled BASELINE is the ratios' denominator
COURSES = {
    "walls": (
        "hierarchy",
        "the course",
        (
            ("low level alone, flat", "quadruped-flat-pmtg", ()),
            (BASELINE, "quadruped-flat-pmtg", ("env.name=quadruped-walls",)),
            ("hierarchical, IAP high level", "quadruped-walls-iap", ()),
            ("hierarchical, CNN high level", "quadruped-walls-cnn", ()),
            ("hierarchical, blind high level", "quadruped-walls-blind", ()),
        ),
    ),
    "gates": (
        "hierarchy-gates",
        "the gates corridor",
        (
            (BASELINE, "quadruped-flat-pmtg", ("env.name=quadruped-gates",)),
            ("hierarchical, IAP high level (depth)", "quadruped-gates-iap", ()),
            ("hierarchical, blind high level", "quadruped-gates-blind", ()),
        ),
    ),
}


def work(job: dict) -> dict:
    """One program: ``train`` for ``iterations`` in a scratch directory, compiled from scratch."""
    from iap_mjx import configs, runtime
    from iap_mjx.es.train import train

    config = configs.apply_overrides(configs.get(job["preset"]), job["overrides"])
    with runtime.persistent_cache_off(), tempfile.TemporaryDirectory() as run_dir:
        history = train(config, run_dir=run_dir, progress=False).history
    steady = history[1:]  # the first iteration's call follows the compile
    return {
        "iteration_s": statistics.median(row["run_s"] for row in steady),
        "env_steps_per_s": statistics.median(row["env_steps_per_s"] for row in steady),
        "compile_s": history[0]["compile_s"],
        "parameters": history[0]["parameters"],
        "population": config.es.population_size,
        "eval_episodes": config.run.eval_episodes,
    }


def run_job(job: dict) -> dict:
    """``job`` in a fresh interpreter set up as the CLI is (devices, constants, no GL)."""
    done = subprocess.run(
        [sys.executable, __file__, "--worker", json.dumps(job)], capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        raise RuntimeError(f"worker {job} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def worker_main(job: dict) -> None:
    from iap_mjx import runtime

    runtime.setup()
    print(json.dumps(work(job)))


def table(rows: list[tuple[str, str, dict]]) -> str:
    base = dict((label, row) for label, _, row in rows)[BASELINE]
    lines = [
        "| program | preset | parameters | s / iteration | env steps/s | x the low level alone on the course "
        "(env steps/s) | compile s |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for label, preset, row in rows:
        lines.append(
            f"| {label} | `{preset}` | {row['parameters']:,} | {row['iteration_s']:.1f} | "
            f"{row['env_steps_per_s']:,.0f} | {row['env_steps_per_s'] / base['env_steps_per_s']:.2f} | "
            f"{row['compile_s']:.0f} |"
        )
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--iterations", type=int, default=4, help="ES iterations per program (>= 2)")
    parser.add_argument("--course", choices=sorted(COURSES), default="walls", help="the course the programs run on")
    parser.add_argument("--output", type=Path, default=report.ROOT / "BENCHMARKS.md")
    parser.add_argument("--no-write", action="store_true")
    args = parser.parse_args()
    if args.worker:
        worker_main(json.loads(args.worker))
        return 0
    if args.iterations < 2:
        parser.error(f"--iterations {args.iterations}: the first iteration compiles; use >= 2")

    from iap_mjx import runtime

    runtime.set_host_device_count()  # as the workers do, so that machine_line() names their devices
    section, course_name, programs = COURSES[args.course]
    common = (f"run.iterations={args.iterations}", "run.checkpoint_every=0", "run.tensorboard=false")
    started = time.perf_counter()
    load_before = os.getloadavg()[0]
    rows = [
        (label, preset, run_job({"preset": preset, "overrides": [*overrides, *common]}))
        for label, preset, overrides in programs
    ]
    total_s = time.perf_counter() - started
    body = table(rows)
    print(body)
    print(f"total {total_s:.0f} s")
    if args.no_write:
        return 0
    command = "python benchmarks/hierarchy.py" + (f" --iterations {args.iterations}" if args.iterations != 4 else "")
    command += f" --course {args.course}" if args.course != "walls" else ""
    first = rows[0][2]
    report.write_section(
        args.output,
        section,
        (
            f"## The hierarchical quadruped policies on {course_name} vs the PMTG low level alone\n\n"
            f"Measured on {report.machine_line()}, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
            f"{total_s / 60:.0f} min in all, the machine otherwise idle (1-min load average "
            f"{load_before:.1f} before, {os.getloadavg()[0]:.1f} after). Command: `{command}`.\n\n"
            f"Each program trains {args.iterations} ES iterations (population {first['population']}, "
            f"{first['eval_episodes']} evaluation episodes of the centre per iteration) in its own process; "
            "s / iteration and env steps/s are the medians over the iterations after the first (every "
            "simulated control step: the population's episodes and the centre's evaluation); compile is "
            "the first iteration's with the persistent compilation cache off. Flat episodes last 500 "
            "control steps, the courses' 1,000, so env steps/s is the figure that compares.\n\n" + body
        ),
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
