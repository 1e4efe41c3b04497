"""The README's main command as a newcomer meets it: wall time from an empty compilation cache,
the return it ends at, and where the time goes.

Runs the README's ``iap-mjx train ...`` command (read from README.md, as the tests do) once per
seed, each in a fresh directory with an empty compilation cache, and writes the ``first-run``
section of ``RESULTS.md`` and ``benchmarks/first-run.png`` (evaluation return per iteration).
Seed 0 is the README's command exactly; other seeds add ``run.seed=K`` after the preset.

Run it alone on the machine (it measures wall-clock):

    python benchmarks/first_run.py --seeds 3
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import report  # noqa: E402


def run_once(args: list[str], seed: int) -> dict:
    """One cold run in a fresh directory: wall seconds, history rows, stage times."""
    with tempfile.TemporaryDirectory() as work:
        env = dict(os.environ, IAP_MJX_CACHE_DIR=str(Path(work) / "cache"), PYTHONUNBUFFERED="1")
        overrides = [f"run.seed={seed}"] if seed else []  # after the preset's name
        command = [sys.executable, "-m", "iap_mjx.cli", *args[:2], *overrides, *args[2:]]
        start = time.perf_counter()
        done = subprocess.run(command, cwd=work, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - start
        if done.returncode:
            raise SystemExit(f"seed {seed} failed:\n{done.stderr}")
        run_dir = Path(work) / args[args.index("--run-dir") + 1]
        rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
        trained = rows[-1]["wall_s"]
        return {
            "seed": seed,
            "wall_s": wall,
            "rows": rows,
            "compile_s": rows[-1]["compile_s"],
            "train_s": trained - rows[-1]["compile_s"],
            "after_training_s": wall - trained,
            "stderr_warnings": [
                line for line in done.stderr.splitlines() if "warn" in line.lower() or "error" in line.lower()
            ],
        }


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for result in results:
        rows = result["rows"]
        ax.plot(
            [r["iteration"] for r in rows],
            [r["eval_return"] for r in rows],
            "o-",
            markersize=3,
            label=f"seed {result['seed']}",
        )
    ax.set_xlabel("ES iteration")
    ax.set_ylabel("evaluation return (centre params)")
    ax.set_title("the README's main command")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--output", type=Path, default=ROOT / "RESULTS.md")
    options = parser.parse_args()
    args = report.readme_main_command()
    load_before = os.getloadavg()[0]
    started = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    results = [run_once(args, seed) for seed in range(options.seeds)]
    load_after = os.getloadavg()[0]
    png = ROOT / "benchmarks" / "first-run.png"
    plot(results, png)
    lines = [
        "| seed | wall s (cold cache) | compile s | training s | curve + video s | iterations | "
        "first eval return | final eval return | warning lines on stderr |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        rows = r["rows"]
        lines.append(
            f"| {r['seed']} | {r['wall_s']:.0f} | {r['compile_s']:.0f} | {r['train_s']:.0f} | "
            f"{r['after_training_s']:.0f} | {len(rows)} | {rows[0]['eval_return']:.1f} | "
            f"{rows[-1]['eval_return']:.1f} | {len(r['stderr_warnings'])} |"
        )
    finals = [r["rows"][-1]["eval_return"] for r in results]
    body = (
        "## The first run: the README's main command\n\n"
        f"Command: `python benchmarks/first_run.py --seeds {options.seeds}`, which runs "
        f"`iap-mjx {shlex.join(args)}` (seed 0; `run.seed=K` after the preset for the others) in a fresh "
        "directory with an empty compilation cache, after `pip install`. Measured on "
        f"{report.machine_line()}, started {started}; 1-min load average before/after: "
        f"{load_before:.1f}/{load_after:.1f}.\n\n"
        "Wall time is the whole command (imports, compilation, training, the reward curve and "
        "the video); compile is the ES iteration's compile (the video's episode program compiles "
        "beside it, in a background thread); the last timed column is what follows training "
        "(the reward curve, the video's rollout and its encoding).\n\n"
        + "\n".join(lines)
        + f"\n\nFinal evaluation return: mean {sum(finals) / len(finals):.1f} "
        f"(min {min(finals):.1f}) over {len(finals)} seeds.\n\n![curves](benchmarks/first-run.png)\n"
    )
    print(body)
    report.write_section(options.output, "first-run", body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
