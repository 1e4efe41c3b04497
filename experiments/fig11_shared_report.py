"""Shared courses or each member's own (RESULTS.md, section ``fig11-shared-tuning``): a
markdown table of iterations 41-60 of the seed-0 runs on each, and what the rule fixed before
the runs decides.

The rule: per run, the walls passed by the centre in its evaluations of iterations 41-60 (8
fresh courses each, 160 episodes); per way of drawing courses, the mean over the IAP and the CNN
run. Shared courses are adopted for a new set of nine Figure 11 runs if their score beats the
own courses' by more than ``MARGIN``. The blind control is reported, never tuned on.

    python experiments/fig11_shared_report.py [SHARED_DIR [OWN_DIR]]

``SHARED_DIR`` holds ``quadruped-walls-<p>-seed0`` trained with ``es.shared_episodes=true``
(default ``experiments/fig11-shared-tuning``: copies of the runs' ``config.json`` and
``metrics.csv``), ``OWN_DIR`` the same runs without it (default ``pretrained/quadruped-turn``,
the ``fig11-turn`` runs).
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

FIRST, LAST = 41, 60  # the iterations read
MARGIN = 0.1  # walls per episode: about two standard errors of the difference of two scores
HIGH_LEVELS = ("iap", "cnn", "blind")
TUNED_ON = ("iap", "cnn")


def read(run: Path) -> dict[str, float]:
    """What the rule reads of one run's ``metrics.csv``, iterations ``FIRST``-``LAST``."""
    with open(run / "metrics.csv") as file:
        rows = [row for row in csv.DictReader(file) if FIRST <= int(row["iteration"]) <= LAST]
    if len(rows) != LAST - FIRST + 1:
        raise SystemExit(f"{run}: iterations {FIRST}-{LAST} not all there yet ({len(rows)} rows)")
    shared = json.loads((run / "config.json").read_text())["es"].get("shared_episodes", False)
    mean = lambda key: sum(float(row[key]) for row in rows) / len(rows)  # noqa: E731
    return {
        "shared": shared,
        "eval_walls": mean("eval_walls_passed"),
        "population_walls": mean("walls_passed_mean"),
        "eval_return": mean("eval_return"),
        "population_return": mean("return_mean"),
        "eval_fell_off": mean("eval_fell_off"),
    }


def main(shared_dir: str = "experiments/fig11-shared-tuning", own_dir: str = "pretrained/quadruped-turn") -> None:
    runs = {
        (way, p): read(Path(folder) / f"quadruped-walls-{p}-seed0")
        for way, folder in (("shared", shared_dir), ("own", own_dir))
        for p in HIGH_LEVELS
    }
    for (way, p), run in runs.items():
        if run["shared"] != (way == "shared"):
            raise SystemExit(f"{way} courses' {p} run has es.shared_episodes={run['shared']}")
    print(
        f"| courses | high level | walls passed, centre's evaluations {FIRST}-{LAST} | walls passed, population | "
        "return, evaluations | return, population | fell off, evaluations |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    for (way, p), r in runs.items():
        print(
            f"| {way} | {p} | {r['eval_walls']:.2f} | {r['population_walls']:.2f} | {r['eval_return']:.2f} | "
            f"{r['population_return']:.2f} | {r['eval_fell_off']:.2f} |"
        )
    score = {way: sum(runs[way, p]["eval_walls"] for p in TUNED_ON) / len(TUNED_ON) for way in ("shared", "own")}
    adopted = score["shared"] > score["own"] + MARGIN
    print()
    print(
        f"Score (IAP and CNN): shared {score['shared']:.3f}, own {score['own']:.3f}; "
        f"shared courses {'adopted' if adopted else 'not adopted'} (margin {MARGIN})."
    )


if __name__ == "__main__":
    main(*sys.argv[1:])
