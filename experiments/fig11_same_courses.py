"""Figure 11's runs of 400 iterations on the courses of the 200-iteration evaluation.

Every course evaluation draws its courses from the tables' seed (2021) and the checkpoint's
iteration, so ``reproduce fig11 run.iterations=400`` evaluates its final checkpoints on other
courses than the 200-iteration report did. The rule in RESULTS.md (``fig11-analysis``) asked for
the same courses at both budgets: this script evaluates each run's latest checkpoint on the
episodes of iteration ``--episodes-of`` (``es.evaluate_run_episodes(..., episodes_of=...)``),
eyes open and, for the seeing policies, closed (``policy.blind=true``), prints Figure 11's table
and bars on them (``courses.summaries`` and ``fig11.table``, as the report) and, with ``--out``, writes the per-episode
numbers as JSON.

    python experiments/fig11_same_courses.py pretrained/quadruped-400 --out experiments/fig11-400/same-courses.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from iap_mjx import runtime

# before JAX starts, as the CLI: two CPU devices and the same sharded batches as the report's own
# evaluation (the trot is chaotic, so another layout's float32 rounding plays other episodes)
runtime.setup()

import numpy as np  # noqa: E402

from iap_mjx import es  # noqa: E402
from iap_mjx.configs.training import EVAL_SEED  # noqa: E402
from iap_mjx.es import checkpoint  # noqa: E402
from iap_mjx.es.metrics_log import read_history  # noqa: E402
from iap_mjx.paper import courses, fig11  # noqa: E402

STATISTICS = ("return", *fig11.STATISTICS)


def evaluate(run_dir: Path, *, episodes: int, episodes_of: int, eyes_closed: bool) -> dict[str, list[float]]:
    """``{statistic: (episodes,) list}`` of the run's latest checkpoint on iteration
    ``episodes_of``'s evaluation episodes."""
    condition = ("policy.blind=true",) if eyes_closed else ()
    result = es.evaluate_run_episodes(
        run_dir, episodes=episodes, seed=EVAL_SEED, overrides=condition, episodes_of=episodes_of
    )
    return {name: np.asarray(result[name], float).tolist() for name in STATISTICS}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, help="the folder holding quadruped-walls-{iap,cnn,blind}-seed<k>")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--episodes-of", type=int, default=200, help="the iteration whose courses to use")
    parser.add_argument("--out", type=Path, help="a JSON file for the per-episode numbers")
    args = parser.parse_args()

    rows, parameters = [], {}
    for label, preset in fig11.POLICIES.items():
        for seed in range(args.seeds):
            run = args.runs / f"{preset}-seed{seed}"
            last = read_history(run)[-1]
            parameters[label] = int(last["parameters"])
            row = {"policy": label, "run": run.name, "finished": True, "iterations": checkpoint.latest_step(run)}
            row["env_steps"] = int(last["env_steps"])
            row["course"] = evaluate(run, episodes=args.episodes, episodes_of=args.episodes_of, eyes_closed=False)
            if label in fig11.SEEING:
                row["eyes_closed"] = evaluate(
                    run, episodes=args.episodes, episodes_of=args.episodes_of, eyes_closed=True
                )
            rows.append(row)
    summaries = courses.summaries(rows, parameters, fig11.STATISTICS)
    print(f"Courses of iteration {args.episodes_of} ({args.episodes} episodes, seed {EVAL_SEED}):\n")
    print(fig11.table(summaries, seeds=args.seeds))
    if args.out is not None:
        names = {"course": "course", "eyes_closed": "course-eyes-closed"}  # the JSON's names: eval.json's
        episodes = {f"{row['run']}/{name}": row[entry] for row in rows for entry, name in names.items() if entry in row}
        args.out.write_text(json.dumps({"episodes_of": args.episodes_of, "episodes": episodes}, indent=1) + "\n")


if __name__ == "__main__":
    main()
