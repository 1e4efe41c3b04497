"""Full pixel pipeline throughput: physics + 100x100 camera + attention + controller + ES update.

Trains each preset for a few iterations with ``iap_mjx.es.train`` (population sharded over
every XLA CPU device) and reports env-steps/s of the steady-state iterations (every simulated
step: population, and centre evaluation) and the compile time, IAP next to brute force
measured in the same run.

    python benchmarks/pipeline.py            # writes the pipeline section of BENCHMARKS.md
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from iap_mjx import runtime  # noqa: E402

runtime.set_host_device_count()
CACHE_DIR = runtime.enable_compilation_cache()
CACHE_WAS_COLD = not any(CACHE_DIR.iterdir())  # before this run compiled anything

import report  # noqa: E402
from iap_mjx import configs  # noqa: E402
from iap_mjx.es import train  # noqa: E402

PRESETS = ["cheetah-run-pixels", "cheetah-run-pixels-relu", "cheetah-run-pixels-brute"]


def measure(preset: str, overrides: list[str]) -> dict:
    config = configs.apply_overrides(configs.get(preset), overrides)
    with tempfile.TemporaryDirectory() as run_dir:
        history = train(config, run_dir=run_dir, progress=False).history
    steady = [row["env_steps_per_s"] for row in history[1:]]  # the first iteration includes compile
    return {"preset": preset, "compile_s": history[0]["compile_s"],
            "steps_per_s": statistics.median(steady), "iterations": len(history)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--population", type=int, default=64)
    parser.add_argument("--episode-length", type=int, default=250)
    parser.add_argument("--iterations", type=int, default=4)
    parser.add_argument("--action-repeat", type=int, default=1,
                        help="1: every control step renders a frame and runs the policy")
    parser.add_argument("--output", type=Path, default=report.ROOT / "BENCHMARKS.md")
    args = parser.parse_args()
    overrides = [f"es.population_size={args.population}", f"env.episode_length={args.episode_length}",
                 f"env.action_repeat={args.action_repeat}",
                 f"run.iterations={args.iterations}", "run.checkpoint_every=0", "run.tensorboard=false"]
    rows = [measure(preset, overrides) for preset in PRESETS]
    base = rows[-1]["steps_per_s"]
    lines = ["| preset | env-steps/s | x brute | compile s |", "|---|---:|---:|---:|"]
    for row in rows:
        lines.append(f"| `{row['preset']}` | {row['steps_per_s']:.0f} | {row['steps_per_s'] / base:.2f} | "
                     f"{row['compile_s']:.1f} |")
    body = "\n".join(lines)
    print(body)
    command = (f"python benchmarks/pipeline.py --population {args.population} "
               f"--episode-length {args.episode_length} --iterations {args.iterations} "
               f"--action-repeat {args.action_repeat}")
    report.write_section(args.output, "pipeline", (
        "## Full pixel pipeline (physics + 100x100 camera + attention + controller + ES)\n\n"
        f"Measured on {report.machine_line()}. Command: `{command}`.\n\n"
        "Steady-state env-steps/s (median over the iterations after the first, counting every "
        "simulated step), and the compile time of the first iteration; \"x brute\" divides by "
        "the brute-force attention preset measured in the same run. "
        + ("The persistent compilation cache was empty at the start (cold compile; run with "
           "`IAP_MJX_CACHE_DIR=$(mktemp -d)` to reproduce that)."
           if CACHE_WAS_COLD else
           "The persistent compilation cache already held programs, so the compile column is "
           "mostly cache loading; run with `IAP_MJX_CACHE_DIR=$(mktemp -d)` for a cold compile.")
        + "\n\n" + body))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
