"""``experiments/table1_paired_report.py``, the rule of RESULTS.md's ``table1-inputs-tuning``:
the paired difference and its standard error against a hand computation, and the verdict
(d > 2 SE on one task and > -2 SE on the other; the larger sum of d / SE among those that do)."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "experiments" / "table1_paired_report.py"


def _report():
    spec = importlib.util.spec_from_file_location("table1_paired_report", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _write(folder: Path, runs: dict[str, list[float]]) -> None:
    for name, returns in runs.items():
        (folder / name).mkdir()
        (folder / name / "eval-100.json").write_text(json.dumps({"returns": returns, "episodes": len(returns)}))


def test_paired_difference_and_its_standard_error():
    d, se = _report().paired([3.0, 5.0, 10.0], [1.0, 1.0, 1.0])  # differences 2, 4, 9
    assert d == pytest.approx(5.0)
    assert se == pytest.approx(math.sqrt(((2 - 5) ** 2 + (4 - 5) ** 2 + (9 - 5) ** 2) / 2) / math.sqrt(3))


def test_the_verdict_follows_the_rule(tmp_path, capsys):
    base = [0.0, 10.0, 20.0, 30.0]
    noise = [1.0, -1.0, 1.0, -1.0]  # the SE of (base + c + noise) - base: sqrt(4/3) / sqrt(4) = 0.577

    def shifted(c: float) -> list[float]:
        return [b + c + n for b, n in zip(base, noise)]

    _write(
        tmp_path,
        {
            "base-cartpole-swingup": base,
            "base-reacher-easy": base,
            "episodes2-cartpole-swingup": shifted(3.0),  # d / SE = 3 / 0.577 = +5.2: qualifies
            "episodes2-reacher-easy": shifted(-1.0),  # -1.7: above -2
            "fs2-patches-cartpole-swingup": shifted(4.0),  # +6.9, but ...
            "fs2-patches-reacher-easy": shifted(-1.5),  # ... -2.6 here: does not qualify
        },
    )
    _report().main([str(tmp_path)])
    out = capsys.readouterr().out
    assert "adopted: episodes2 (qualifying: ['episodes2'])" in out
    assert "| fs2-patches | reacher-easy | 13.5 | 15.0 | -1.5 | 0.6 | -2.60 |" in out
