"""A candidate setting for Figure 11's runs against the ``fig11-turn`` runs it would replace
(RESULTS.md, sections ``fig11-shared-tuning`` and ``fig11-fall-tuning``): a markdown table of
iterations 41-60 of the seed-0 runs of both, and what the rule fixed before the runs decides.

The rule: per run, the walls passed by the centre in its evaluations of iterations 41-60 (8
fresh courses each, 160 episodes); per setting, the mean over the IAP and the CNN run. The
candidate is adopted for a new set of nine Figure 11 runs if its score beats the baseline's by
more than ``MARGIN``. The blind control is reported, never tuned on.

    python experiments/fig11_candidate_report.py CANDIDATE_DIR [BASELINE_DIR]

Each folder holds ``quadruped-walls-<p>-seed0`` for p in iap, cnn, blind (``config.json`` and
``metrics.csv``); ``BASELINE_DIR`` defaults to ``pretrained/quadruped-turn``, the
``fig11-turn`` runs. The settings in which the candidate's configs differ are printed first.
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
    mean = lambda key: sum(float(row[key]) for row in rows) / len(rows)  # noqa: E731
    return {
        "eval_walls": mean("eval_walls_passed"),
        "population_walls": mean("walls_passed_mean"),
        "eval_return": mean("eval_return"),
        "population_return": mean("return_mean"),
        "eval_fell_off": mean("eval_fell_off"),
    }


def settings(run: Path) -> dict[str, object]:
    """The run's ES settings and env overrides, ``{"es.<field>" or "env.<name>": value}``."""
    config = json.loads((run / "config.json").read_text())
    return {
        **{f"es.{k}": v for k, v in config["es"].items()},
        **{f"env.{k}": v for k, v in config["env"]["overrides"].items()},
    }


def main(candidate_dir: str, baseline_dir: str = "pretrained/quadruped-turn") -> None:
    folders = {"candidate": Path(candidate_dir), "baseline": Path(baseline_dir)}
    run = lambda way, p: folders[way] / f"quadruped-walls-{p}-seed0"  # noqa: E731
    ours, theirs = settings(run("candidate", "iap")), settings(run("baseline", "iap"))
    differ = {
        key: (theirs.get(key), ours.get(key)) for key in sorted({*ours, *theirs}) if ours.get(key) != theirs.get(key)
    }
    print("Settings (baseline -> candidate): " + ", ".join(f"`{k}` {a} -> {b}" for k, (a, b) in differ.items()))
    print()
    runs = {(way, p): read(run(way, p)) for way in folders for p in HIGH_LEVELS}
    print(
        f"| run | high level | walls passed, centre's evaluations {FIRST}-{LAST} | walls passed, population | "
        "return, evaluations | return, population | fell off, evaluations |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    for (way, p), r in runs.items():
        print(
            f"| {way} | {p} | {r['eval_walls']:.2f} | {r['population_walls']:.2f} | {r['eval_return']:.2f} | "
            f"{r['population_return']:.2f} | {r['eval_fell_off']:.2f} |"
        )
    score = {way: sum(runs[way, p]["eval_walls"] for p in TUNED_ON) / len(TUNED_ON) for way in folders}
    adopted = score["candidate"] > score["baseline"] + MARGIN
    print()
    print(
        f"Score (IAP and CNN): candidate {score['candidate']:.3f}, baseline {score['baseline']:.3f}; "
        f"the candidate is {'adopted' if adopted else 'not adopted'} (margin {MARGIN})."
    )


if __name__ == "__main__":
    if len(sys.argv) not in (2, 3):
        raise SystemExit(__doc__)
    main(*sys.argv[1:])
