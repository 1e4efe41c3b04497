"""Table 1's second short test (RESULTS.md, section ``table1-inputs-tuning``): each candidate's
final centre against the baseline's on the same evaluation episodes, as the rule fixed before
the runs reads them.

Per task: ``d`` = the mean over the common episodes of (candidate's return - baseline's), and
its standard error, the sample std of those paired differences over sqrt(episodes). Both runs'
``eval-100.json`` are ``iap-mjx eval --episodes 100`` outputs with the same evaluation seed, so
episode ``i`` has the same draw (target, pole, picture, camera, colours) in both.

    python experiments/table1_paired_report.py [FOLDER]

``FOLDER`` (default ``experiments/table1-inputs-tuning``) holds ``<setting>-<task>/eval-100.json``
with the setting ``base`` as the baseline.
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

TASKS = ("cartpole-swingup", "reacher-easy")
CANDIDATES = ("episodes2", "fs2-patches")
BOUND = 2.0  # the rule's multiple of the standard error


def returns(folder: Path, setting: str, task: str) -> list[float]:
    """The run's per-episode returns."""
    data = json.loads((folder / f"{setting}-{task}" / "eval-100.json").read_text())
    return data["returns"]


def paired(candidate: list[float], baseline: list[float]) -> tuple[float, float]:
    """``(d, SE)`` of the per-episode differences."""
    if len(candidate) != len(baseline):
        raise SystemExit(f"{len(candidate)} candidate episodes against {len(baseline)} baseline ones")
    diffs = [c - b for c, b in zip(candidate, baseline)]
    return statistics.mean(diffs), statistics.stdev(diffs) / len(diffs) ** 0.5


def main(argv: list[str]) -> int:
    folder = Path(argv[0]) if argv else Path("experiments/table1-inputs-tuning")
    print("| candidate | task | candidate mean | baseline mean | d | SE of d | d / SE |")
    print("|---|---|---:|---:|---:|---:|---:|")
    verdicts = {}
    for candidate in CANDIDATES:
        ratios = []
        for task in TASKS:
            c = returns(folder, candidate, task)
            b = returns(folder, "base", task)
            d, se = paired(c, b)
            ratios.append(d / se)
            print(
                f"| {candidate} | {task} | {statistics.mean(c):.1f} | {statistics.mean(b):.1f} "
                f"| {d:+.1f} | {se:.1f} | {d / se:+.2f} |"
            )
        qualifies = max(ratios) > BOUND and min(ratios) > -BOUND
        verdicts[candidate] = (qualifies, sum(ratios))
    passing = {name: score for name, (ok, score) in verdicts.items() if ok}
    print()
    if passing:
        print(f"adopted: {max(passing, key=passing.__getitem__)} (qualifying: {sorted(passing)})")
    else:
        print("adopted: none (no candidate has d > 2 SE on one task and d > -2 SE on the other)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
