"""``iap-mjx reproduce fig7``: the patch size x l grid, then d_qk at the grid's best cell only
once the grid is finished; bad input fails before anything compiles. Training and evaluation
are ``iap_mjx.paper.report_runs``'s and ``es.evaluate_run``'s (tested elsewhere); here finished runs
are written by hand and the evaluation is a recorder, so the sweep's own logic runs in seconds."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fake_runs import fake_run

from iap_mjx import cli, configs
from iap_mjx.paper import fig7

ITERATIONS = ("run.iterations=2",)


def _fake_run(out, cell, iterations=2):
    config = configs.apply_overrides(configs.get(fig7.PRESET), (*ITERATIONS, *fig7.cell_overrides(*cell)))
    fake_run(out / fig7.run_name(*cell, 0), config, iterations, [10.0 * i for i in range(1, iterations + 1)])


@pytest.fixture
def evaluations(monkeypatch):
    """Recorded calls; the return of cell (p, l, d) is 100 + 10 p - l + d: best grid cell (8, 5)."""
    calls = []

    def evaluate_run(run_dir, *, episodes, seed, overrides):
        calls.append(run_dir.name)
        p, l, d = (int(part[1:]) for part in run_dir.name.split("-")[1:4])
        return np.full(episodes, 100.0 + 10 * p - l + d)

    from iap_mjx import es

    monkeypatch.setattr(es, "evaluate_run", evaluate_run)
    return calls


def test_bad_settings_fail_before_anything_runs(tmp_path, capsys):
    with pytest.raises(ValueError, match="policy.top_l"):
        fig7.reproduce_fig7(tmp_path, overrides=("policy.top_l=3",))
    with pytest.raises(ValueError, match="heigth"):
        fig7.reproduce_fig7(tmp_path, overrides=("env.heigth=64",))
    with pytest.raises(ValueError, match="episodes"):
        fig7.reproduce_fig7(tmp_path, episodes=0)
    assert not list(tmp_path.iterdir())
    assert cli.main(["reproduce", "fig7", "policy.d_qk=2", "--out", str(tmp_path)]) == 2
    assert "policy.d_qk" in capsys.readouterr().err


def test_d_qk_row_waits_for_the_whole_grid_then_runs_at_its_best_cell(tmp_path, evaluations):
    grid = [(p, l) for p in fig7.PATCH_SIZES for l in fig7.TOP_LS]
    for p, l in grid[:-1]:
        _fake_run(tmp_path, (p, l, 4))
    _fake_run(tmp_path, (8, 5, 2))  # a d_qk run exists, but the grid is not finished
    markdown = fig7.reproduce_fig7(tmp_path, overrides=ITERATIONS, episodes=3, train=False)
    assert "not chosen yet" in markdown
    assert len(evaluations) == 8 and "fig7-p8-l5-d2-seed0" not in evaluations
    _fake_run(tmp_path, (*grid[-1], 4), iterations=1)  # the last cell unfinished
    assert "not chosen yet" in fig7.reproduce_fig7(tmp_path, overrides=ITERATIONS, episodes=3, train=False)
    _fake_run(tmp_path, (*grid[-1], 4))
    _fake_run(tmp_path, (2, 5, 8))  # d_qk off the best cell: never read
    markdown = fig7.reproduce_fig7(
        tmp_path, overrides=ITERATIONS, episodes=3, train=False, results=tmp_path / "RESULTS.md"
    )
    assert "Best grid cell (patch size, l): (8, 5)" in markdown
    assert "fig7-p2-l5-d8-seed0" not in evaluations
    rows = [line for line in markdown.splitlines() if line.startswith("| ") and line[2].isdigit()]
    assert len(rows) == 10  # nine grid cells and the one d_qk run trained so far
    assert rows[-1].startswith("| 8 | 5 | 2 | 1,200 | 177.0 ± 0.0 (3) |")
    assert (
        "`iap-mjx train dcs-cartpole-swingup run.iterations=2 policy.patch_size=8 policy.top_l=5 policy.d_qk=2"
        in rows[-1]
    )
    stored = json.loads((tmp_path / "fig7.json").read_text())
    assert stored["best"] == [8, 5] and (tmp_path / "fig7.png").stat().st_size > 0
    assert "<!-- BEGIN fig7 -->" in (tmp_path / "RESULTS.md").read_text()
    count = len(evaluations)
    fig7.reproduce_fig7(tmp_path, overrides=ITERATIONS, episodes=3, train=False)
    assert len(evaluations) == count  # evaluations are read back from each run's eval.json


def test_the_patch_count_follows_the_frame(tmp_path, evaluations):
    """L is the policy's own patch count on the run's frames, not the paper's 240x320."""
    small = ("env.height=120", "env.width=160")
    config = configs.apply_overrides(configs.get(fig7.PRESET), (*ITERATIONS, *small, *fig7.cell_overrides(8, 5, 4)))
    fake_run(tmp_path / fig7.run_name(8, 5, 4, 0), config, 2, [10.0, 20.0])
    markdown = fig7.reproduce_fig7(tmp_path, overrides=(*ITERATIONS, *small), episodes=3, train=False)
    assert "| 8 | 5 | 4 | 300 |" in markdown  # (120 / 8) x (160 / 8)


def test_the_command_line_sets_the_seed(tmp_path, monkeypatch):
    seen = {}
    monkeypatch.setattr(fig7, "reproduce_fig7", lambda out, **kwargs: seen.update(kwargs) or "")
    assert cli.main(["reproduce", "fig7", "--seed", "2", "--report-only", "--out", str(tmp_path)]) == 0
    assert seen["seed"] == 2 and seen["train"] is False
