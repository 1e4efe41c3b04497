"""Figure 11's policies compared course by course: the reading of RESULTS.md's section
`fig11-400-100-reading`, from the evaluations `iap-mjx reproduce fig11` stored.

Every run of a Figure 11 report is evaluated on the same courses (drawn from the evaluation seed
and the checkpoint's iteration), so the policies can be compared on each course: per policy,
walls passed on course ``c`` averaged over its seeds; per pair of policies, the mean over courses
of the difference and its standard error over courses (which separates the policies from the
courses' luck, not from the seeds'); per seeing policy, eyes open minus closed pooled over its
paired episodes (each run's episode on a course against the same run's with its eyes closed).

    python experiments/fig11_paired.py pretrained/quadruped-400 --entry course@400x100s2021
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

POLICIES = {"IAP": "quadruped-walls-iap", "CNN": "quadruped-walls-cnn", "blind": "quadruped-walls-blind"}
PAIRS = (("IAP", "blind"), ("CNN", "blind"), ("IAP", "CNN"))
SEEING = ("IAP", "CNN")
STATISTIC = "walls_passed"


def closed_entry(entry: str) -> str:
    """The eyes-closed entry beside ``entry`` (``course@...`` -> ``course-eyes-closed@...``)."""
    name, at = entry.split("@", 1)
    return f"{name.replace('course', 'course-eyes-closed', 1)}@{at}"


def episodes(root: Path, preset: str, entry: str, seeds: int) -> np.ndarray:
    """``(seeds, courses)``: walls passed on each course by each seed's run."""
    rows = []
    for seed in range(seeds):
        stored = json.loads((root / f"{preset}-seed{seed}" / "eval.json").read_text())
        if entry not in stored:
            raise SystemExit(f"{preset}-seed{seed} has no evaluation {entry!r}; run the report first")
        rows.append(stored[entry][STATISTIC])
    return np.asarray(rows, dtype=float)


def mean_and_se(values: np.ndarray) -> tuple[float, float]:
    """The mean of ``values`` and its standard error (sample std, ddof 1, over sqrt(n))."""
    return float(values.mean()), float(values.std(ddof=1) / math.sqrt(values.size))


def report(root: Path, entry: str, seeds: int) -> str:
    """The markdown of the comparison."""
    open_ = {label: episodes(root, preset, entry, seeds) for label, preset in POLICIES.items()}
    per_course = {label: walls.mean(axis=0) for label, walls in open_.items()}
    courses = next(iter(per_course.values())).size
    lines = [
        f"Walls passed per course, {courses} courses (`{entry}`), each policy's {seeds} seeds averaged course "
        "by course; differences with their standard error over the courses:",
        "",
        "| comparison | mean difference | SE | in SE | courses better / worse |",
        "|---|---:|---:|---:|---|",
    ]
    for a, b in PAIRS:
        difference = per_course[a] - per_course[b]
        mean, se = mean_and_se(difference)
        better, worse = int((difference > 0).sum()), int((difference < 0).sum())
        lines.append(f"| {a} - {b} | {mean:+.3f} | {se:.3f} | {mean / se:+.1f} | {better} / {worse} |")
    lines += [
        "",
        f"Eyes open minus closed, pooled over each seeing policy's {seeds * courses} paired episodes:",
        "",
        "| policy | open | closed | open - closed | SE | in SE |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for label in SEEING:
        closed = episodes(root, POLICIES[label], closed_entry(entry), seeds)
        mean, se = mean_and_se((open_[label] - closed).ravel())
        lines.append(
            f"| {label} | {open_[label].mean():.3f} | {closed.mean():.3f} | {mean:+.3f} | {se:.3f} | {mean / se:+.1f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", type=Path, help="the folder of the runs (e.g. pretrained/quadruped-400)")
    parser.add_argument("--entry", required=True, help="the eval.json entry, e.g. course@400x100s2021")
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    print(report(args.root, args.entry, args.seeds))


if __name__ == "__main__":
    main()
