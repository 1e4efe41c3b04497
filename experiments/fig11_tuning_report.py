"""The course's ES tuning (``experiments/fig11-tuning.sh``): a markdown table of every run and
the setting its rule chooses.

The rule, fixed before the runs: per run, the mean of the last five iterations' evaluation
returns (8 episodes each); per setting, the mean of that over the IAP and the CNN run; the
setting with the highest wins and becomes ``COURSE_ES``. The blind control is never tuned on.

    python experiments/fig11_tuning_report.py [experiments/fig11-tuning]
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

LAST = 5  # evaluations averaged per run


def read(run: Path) -> dict:
    """One run's settings and what the rule reads of its ``metrics.csv``."""
    with open(run / "metrics.csv") as file:
        rows = list(csv.DictReader(file))
    config = json.loads((run / "config.json").read_text())
    es = config["es"]
    last = rows[-LAST:]
    return {
        "run": run.name,
        "high": run.name.split("-", 1)[0],
        "setting": run.name.split("-", 1)[1],
        "learning_rate": es["learning_rate"],
        "sigma": es["sigma"],
        "iterations": int(rows[-1]["iteration"]),
        "first_eval": float(rows[0]["eval_return"]),
        "last_eval": sum(float(r["eval_return"]) for r in last) / len(last),
        "best_eval": max(float(r["eval_return"]) for r in rows),
        "walls": sum(float(r["eval_walls_passed"]) for r in last) / len(last),
        "fell_off": sum(float(r["eval_fell_off"]) for r in last) / len(last),
    }


def main(folder: str = "experiments/fig11-tuning") -> None:
    runs = [read(run) for run in sorted(Path(folder).iterdir()) if (run / "metrics.csv").exists()]
    print(
        f"| run | learning rate | sigma | iterations | first eval | mean of last {LAST} evals | best eval | "
        f"walls passed (last {LAST}) | fell off (last {LAST}) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in runs:
        print(
            f"| `{r['run']}` | {r['learning_rate']} | {r['sigma']} | {r['iterations']} | {r['first_eval']:.2f} | "
            f"{r['last_eval']:.2f} | {r['best_eval']:.2f} | {r['walls']:.2f} | {r['fell_off']:.2f} |"
        )
    by_setting: dict[str, list[float]] = {}
    for r in runs:
        by_setting.setdefault(r["setting"], []).append(r["last_eval"])
    print()
    print("| setting | runs | score (mean over the high levels) |")
    print("|---|---:|---:|")
    for setting, scores in by_setting.items():
        print(f"| {setting} | {len(scores)} | {sum(scores) / len(scores):.3f} |")
    complete = {s: sum(v) / len(v) for s, v in by_setting.items() if len(v) == 2}
    if complete:
        best = max(complete, key=complete.get)
        print(f"\nchosen (settings with both high levels run): {best}")


if __name__ == "__main__":
    main(*sys.argv[1:])
