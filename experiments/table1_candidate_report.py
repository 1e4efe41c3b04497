"""A candidate setting for Table 1 against a baseline run of the same task and seed (RESULTS.md,
section ``table1-shared-tuning``): the centre's evaluation return over iterations 21-30, the
difference ``d`` and its standard error, as the rule fixed before the runs reads them.

Per run: the mean of ``eval_return`` (4 evaluation episodes an iteration) over iterations
21-30 and its standard error (the sample std of those 10 values over sqrt(10)); ``d`` is the
candidate's mean minus the baseline's, its SE the two SEs in quadrature.

    python experiments/table1_candidate_report.py CANDIDATE_RUN BASELINE_RUN [CANDIDATE BASELINE ...]

Each argument is a run directory (or a folder with its ``metrics.csv``), e.g.
``experiments/table1-shared-tuning/shared-cartpole pretrained/dcs/cartpole-swingup-seed0``.
"""

from __future__ import annotations

import csv
import statistics
import sys
from pathlib import Path

FIRST, LAST = 21, 30  # the iterations read


def window(run: Path) -> tuple[float, float]:
    """``(mean, standard error)`` of the run's centre evaluation return over FIRST..LAST."""
    with open(run / "metrics.csv") as f:
        rows = [row for row in csv.DictReader(f) if FIRST <= int(row["iteration"]) <= LAST]
    if len(rows) != LAST - FIRST + 1:
        raise SystemExit(f"{run}: {len(rows)} of iterations {FIRST}-{LAST} in metrics.csv")
    values = [float(row["eval_return"]) for row in rows]
    return statistics.mean(values), statistics.stdev(values) / len(values) ** 0.5


def main(argv: list[str]) -> int:
    if not argv or len(argv) % 2:
        raise SystemExit(__doc__)
    print("| candidate | baseline | candidate mean (SE) | baseline mean (SE) | d | SE of d | d / SE |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for candidate, baseline in zip(argv[::2], argv[1::2]):
        (c, c_se), (b, b_se) = window(Path(candidate)), window(Path(baseline))
        d, se = c - b, (c_se**2 + b_se**2) ** 0.5
        print(
            f"| {candidate} | {baseline} | {c:.1f} ({c_se:.1f}) | {b:.1f} ({b_se:.1f}) | {d:+.1f} | {se:.1f} | {d / se:+.2f} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
