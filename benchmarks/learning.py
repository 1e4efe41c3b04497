"""The learning bar: a preset's evaluation return within a wall-clock budget, several seeds.

Trains ``--preset`` for ``--minutes`` of wall-clock (compile included: ``run.max_minutes``)
on each of ``--seeds`` seeds, then writes the ``--section`` section of ``RESULTS.md``
(default ``learning``): a table and ``benchmarks/<section>_<preset>.png``, evaluation return
against minutes.

``--parallel`` runs the seeds at the same time, one process each: every seed then gets a
share of the cores, so it completes fewer iterations in the budget than it would alone. The
runs are deterministic in their iterations (bit-identical per seed), so a return reached
with a share of the machine is reached no later with all of it.

A seed that finished its budget leaves ``seed-<k>.done`` next to its run directory, and the
same command run again (say, after the machine was taken away) keeps it and trains only the
others. A seed without the marker is trained afresh: resuming it would restart its clock.

Run (heavy; it owns the machine for the budget):

    python benchmarks/learning.py --preset cheetah-run-pixels --seeds 3 --minutes 60 --parallel
"""

from __future__ import annotations

import argparse
import datetime
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import report  # noqa: E402

from iap_mjx.es.metrics_log import read_history  # noqa: E402

DEFAULT_OUT = str(ROOT / "runs" / "learning")


def train_command(preset: str, seed: int, minutes: float, run_dir: Path, overrides: list[str]) -> list[str]:
    return [
        sys.executable,
        "-m",
        "iap_mjx.cli",
        "train",
        preset,
        f"run.seed={seed}",
        f"run.max_minutes={minutes:g}",
        *overrides,
        "--run-dir",
        str(run_dir),
    ]


def run_seeds(args) -> list[Path]:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    run_dirs = [out / f"seed-{seed}" for seed in range(args.seeds)]
    todo = [(seed, run_dir) for seed, run_dir in enumerate(run_dirs) if not run_dir.with_suffix(".done").exists()]
    for _, run_dir in todo:
        shutil.rmtree(run_dir, ignore_errors=True)  # a resumed run would restart its clock
    commands = [train_command(args.preset, seed, args.minutes, run_dir, args.overrides) for seed, run_dir in todo]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}

    def finished(run_dir: Path, code: int) -> int:
        if code == 0:
            run_dir.with_suffix(".done").touch()
        return code

    if args.parallel:
        logs = [open(run_dir.with_suffix(".log"), "w") for _, run_dir in todo]
        procs = [
            subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env) for cmd, log in zip(commands, logs)
        ]
        codes = [finished(run_dir, proc.wait()) for (_, run_dir), proc in zip(todo, procs)]
        for log in logs:
            log.close()
    else:
        codes = []
        for cmd, (_, run_dir) in zip(commands, todo):
            with open(run_dir.with_suffix(".log"), "w") as log:
                code = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
            codes.append(finished(run_dir, code))
    failed = [str(run_dir) for (_, run_dir), code in zip(todo, codes) if code != 0]
    if failed:
        raise SystemExit(f"training failed for {failed}; see the .log next to each run directory")
    return run_dirs


def summarise(run_dir: Path, threshold: float) -> dict:
    rows = [row for row in read_history(run_dir) if "eval_return" in row]
    if not rows:
        raise SystemExit(f"{run_dir} has no evaluation rows")
    reached = next((row for row in rows if row["eval_return"] >= threshold), None)
    return dict(
        run_dir=run_dir,
        rows=rows,
        iterations=int(rows[-1]["iteration"]),
        env_steps=int(rows[-1]["env_steps"]),
        wall_min=rows[-1]["wall_s"] / 60,
        final=rows[-1]["eval_return"],
        best=max(row["eval_return"] for row in rows),
        reached_min=None if reached is None else reached["wall_s"] / 60,
    )


def plot(summaries: list[dict], threshold: float, path: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for seed, summary in enumerate(summaries):
        rows = summary["rows"]
        ax.plot([row["wall_s"] / 60 for row in rows], [row["eval_return"] for row in rows], label=f"seed {seed}")
    ax.axhline(threshold, color="grey", linestyle="--", linewidth=1, label=f"bar {threshold:g}")
    ax.set_xlabel("wall-clock minutes (compile included)")
    ax.set_ylabel("evaluation return (centre params)")
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def section(args, summaries: list[dict], png: Path, when: str) -> str:
    command = " ".join(
        [
            "python benchmarks/learning.py",
            f"--preset {args.preset}",
            f"--seeds {args.seeds}",
            f"--minutes {args.minutes:g}",
        ]
        + (["--parallel"] if args.parallel else [])
        + ([f"--section {args.section}"] if args.section != "learning" else [])
        + ([f"--out {args.out}"] if args.out != DEFAULT_OUT else [])
        + ([f"--threshold {args.threshold:g}"] if args.threshold != 200.0 else [])
        + ([f"--return-per-second {args.return_per_second:g}"] if args.return_per_second else [])
        + args.overrides
    )
    sharing = (
        f"the {args.seeds} seeds ran at the same time, one process each, sharing the 2 cores"
        if args.parallel
        else "one seed at a time, each with the whole machine"
    )
    lines = [
        f"## Learning: `{args.preset}` within {args.minutes:g} minutes, "
        + ("seeds in parallel" if args.parallel else "one seed at a time"),
        "",
        f"Command: `{command}` ({sharing}; {when}).",
        "",
        "Evaluation return: the centre params on the run's evaluation episodes, every iteration. "
        f"Wall-clock includes compilation. Bar: mean evaluation return >= {args.threshold:g}.",
        "",
        "| seed | iterations | env steps | wall min | final eval return | best eval return | first >= bar (min) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for seed, s in enumerate(summaries):
        reached = "-" if s["reached_min"] is None else f"{s['reached_min']:.1f}"
        lines.append(
            f"| {seed} | {s['iterations']} | {s['env_steps']:,} | {s['wall_min']:.1f} | "
            f"{s['final']:.1f} | {s['best']:.1f} | {reached} |"
        )
    finals = [s["final"] for s in summaries]
    lines += [
        "",
        f"Mean final evaluation return over seeds: **{sum(finals) / len(finals):.1f}**. "
        f"Curves: `{png.relative_to(ROOT)}`.",
    ]
    if args.return_per_second:
        speeds = [final / args.return_per_second for final in finals]
        lines += [
            "",
            f"The return is a distance over {args.return_per_second:g} s episodes, so the mean forward "
            "speed over an evaluation episode (falls count as standing still) is final return / "
            f"{args.return_per_second:g} s: "
            + " / ".join(f"{v:.2f}" for v in speeds)
            + f" m/s, mean **{sum(speeds) / len(speeds):.2f} m/s**.",
        ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="cheetah-run-pixels")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--threshold", type=float, default=200.0)
    parser.add_argument("--parallel", action="store_true", help="run the seeds at the same time")
    parser.add_argument("--out", default=DEFAULT_OUT)
    parser.add_argument("--section", default="learning", help="the RESULTS.md section to write; also names the PNG")
    parser.add_argument(
        "--return-per-second",
        type=float,
        default=0.0,
        help="seconds per episode when the return is a distance: report return / it as a speed",
    )
    parser.add_argument(
        "--summarise-only", action="store_true", help="do not train; summarise the run directories already in --out"
    )
    parser.add_argument("overrides", nargs="*", help="config overrides, e.g. env.action_repeat=4")
    args = parser.parse_args(argv)
    started = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    load_before = os.getloadavg()[0]
    if args.summarise_only:
        run_dirs = [Path(args.out) / f"seed-{seed}" for seed in range(args.seeds)]
    else:
        start = time.perf_counter()
        run_dirs = run_seeds(args)
        print(f"trained {len(run_dirs)} seeds in {(time.perf_counter() - start) / 60:.1f} min", flush=True)
    summaries = [summarise(run_dir, args.threshold) for run_dir in run_dirs]
    png = plot(
        summaries,
        args.threshold,
        ROOT / "benchmarks" / f"{args.section}_{args.preset}.png",
        f"{args.preset}: {args.seeds} seeds, {args.minutes:g} min",
    )
    when = (
        f"summarised {started} from the run directories in `{args.out}`"
        if args.summarise_only
        else f"started {started}; 1-min load average before/after: {load_before:.1f}/{os.getloadavg()[0]:.1f}"
    )
    text = section(args, summaries, png, when)
    print(text)
    report.write_section(ROOT / "RESULTS.md", args.section, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
