"""``iap-mjx reproduce gates``: bad input fails before anything compiles; finished runs are
evaluated once each on unseen corridors (stored in the run directory), IAP's also with its eyes
closed, and reported with their corridor statistics and the paired difference; IAP seed 0's
strip is drawn once per checkpoint; exports copy the runs. Training, evaluation and the strip's
drawing are tested elsewhere (test_fig1_fig6.py, test_es_train.py, test_fig10.py); here runs are
written by hand, the evaluation is a recorder and the strip a stand-in PNG."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from fake_runs import fake_run

from iap_mjx import cli, configs
from iap_mjx.configs.training import EVAL_SEED
from iap_mjx.es import checkpoint
from iap_mjx.paper import fig10, gates
from iap_mjx.paper.evaluations import EYES_CLOSED_OVERRIDES

ITERATIONS = ("run.iterations=3",)
# (policy, seed): the evaluation's mean return and gates passed per corridor - 0.5 (below)
RUNS = {("iap", 0): (6.0, 1.0), ("iap", 1): (8.0, 2.0), ("blind", 0): (3.0, 0.0), ("blind", 1): (4.0, 0.0)}


def _run(out, policy, seed, iterations=3):
    preset = f"quadruped-gates-{policy}"
    config = configs.apply_overrides(configs.get(preset), ITERATIONS)
    fake_run(out / f"{preset}-seed{seed}", config, iterations, [float(i) for i in range(1, iterations + 1)])


@pytest.fixture
def evaluations(monkeypatch):
    """Recorded calls; run (policy, seed) of ``RUNS`` gives per corridor returns ``base -+ 1``,
    gates passed ``g + 1, g`` alternately, 2 + seed contact steps, one corridor in four left
    and one in two fallen, ``base`` metres; with its eyes closed (``policy.blind=true``) gates
    passed ``g - 1`` on the first corridor of every pair, ``g`` on the second, return ``base - 2``."""
    calls = []

    def evaluate_run_episodes(run_dir, *, episodes, seed, overrides=(), episodes_of=None):
        assert episodes_of is None  # every run is evaluated on its own checkpoint's episodes
        calls.append((run_dir.name, episodes, seed, tuple(overrides)))
        policy, run_seed = run_dir.name.split("-")[2], int(run_dir.name[-1])
        base, passed = RUNS[policy, run_seed]
        alternate = np.arange(episodes) % 2
        gates_passed = passed + 1.0 - alternate
        if tuple(overrides) == EYES_CLOSED_OVERRIDES:
            base, gates_passed = base - 2.0, passed - 1.0 + alternate
        return {
            "return": base - 1.0 + 2.0 * alternate,
            "gates_passed": gates_passed,
            "collisions": np.full(episodes, 2.0 + run_seed),
            "left_corridor": (np.arange(episodes) % 4 == 3).astype(float),
            "fell_over": alternate.astype(float),
            "distance": np.full(episodes, base),
        }

    from iap_mjx import es

    monkeypatch.setattr(es, "evaluate_run_episodes", evaluate_run_episodes)
    return calls


@pytest.fixture
def strips(monkeypatch):
    """Recorded strip drawings ``(run_dir name, path name, frames)``; each writes a 1x1 PNG and
    returns 4.5 as the episode's return. ``fig10.check`` runs for real (builds the policy)."""
    drawn = []

    def draw_strip(run_dir, env, policy, path, *, frames):
        from PIL import Image

        assert policy.layer.config.patch_size == 4  # the IAP high level that check built
        drawn.append((run_dir.name, path.name, frames))
        Image.new("RGB", (1, 1)).save(path)
        return path, 4.5

    monkeypatch.setattr(fig10, "draw_strip", draw_strip)
    return drawn


def test_bad_input_fails_before_anything_runs(tmp_path, capsys):
    with pytest.raises(ValueError, match="heigth"):
        gates.reproduce_gates(tmp_path, overrides=("env.heigth=64",))
    with pytest.raises(ValueError, match="run.eval_episodes"):
        gates.reproduce_gates(tmp_path, overrides=("run.eval_episodes=0",))
    for setting in ("episodes", "seeds", "frames"):
        with pytest.raises(ValueError, match=setting):
            gates.reproduce_gates(tmp_path, **{setting: 0})
    assert not list(tmp_path.iterdir())
    assert cli.main(["reproduce", "gates", "policy.kernl=relu", "--out", str(tmp_path)]) == 2
    assert "kernl" in capsys.readouterr().err


def test_finished_runs_are_evaluated_once_and_reported_with_the_paired_difference(tmp_path, evaluations, strips):
    _run(tmp_path, "iap", 0)
    _run(tmp_path, "blind", 0)
    _run(tmp_path, "iap", 1, iterations=2)  # unfinished: read as far as it got, not evaluated
    markdown = gates.reproduce_gates(tmp_path, seeds=2, overrides=ITERATIONS, episodes=4, train=False)
    assert sorted(evaluations) == [
        ("quadruped-gates-blind-seed0", 4, EVAL_SEED, ()),
        ("quadruped-gates-iap-seed0", 4, EVAL_SEED, ()),
        ("quadruped-gates-iap-seed0", 4, EVAL_SEED, EYES_CLOSED_OVERRIDES),
    ]
    lines = markdown.splitlines()
    assert lines[2] == (
        "| IAP (`quadruped-gates-iap`) | 617 | 6.0 ± 0.0 | 1.50 ± 0.00 | 2.0 ± 0.0 | 0.25 ± 0.00 | 0.50 ± 0.00 | "
        "6.00 ± 0.00 | 1 of 2 | 3 | 3,000 |"
    )
    assert lines[3] == (
        "| blind (`quadruped-gates-blind`) | 617 | 3.0 ± 0.0 | 0.50 ± 0.00 | 2.0 ± 0.0 | 0.25 ± 0.00 | "
        "0.50 ± 0.00 | 3.00 ± 0.00 | 1 of 2 | 3 | 3,000 |"
    )
    # eyes closed: gates passed 0, 1, 0, 1 against 2, 1, 2, 1: differences 2, 0, 2, 0, sample std 1.155
    assert lines[8:10] == [
        "|---|---:|---:|---:|---:|---|",
        "| IAP | 6.0 ± 0.0 | 4.0 ± 0.0 | 1.50 ± 0.00 | 0.50 ± 0.00 | +1.00 |",
    ]
    assert lines[-1] == (
        "- IAP seed 0: gates passed per corridor, eyes open minus closed on the same 4 corridors: +1.00 "
        "(SE 0.58; +1.7 SE)."
    )
    assert strips == [("quadruped-gates-iap-seed0", "gates-strip.png", 6)]
    assert json.loads((tmp_path / "gates-strip.json").read_text()) == {
        "run_dir": str(tmp_path / "quadruped-gates-iap-seed0"),
        "step": 3,
        "return": 4.5,
        "frames": 6,
    }
    stored = json.loads((tmp_path / "quadruped-gates-iap-seed0" / "eval.json").read_text())
    assert stored["course-eyes-closed@3x4s2021"]["gates_passed"] == [0.0, 1.0, 0.0, 1.0]

    # again: evaluations read back from eval.json, the strip not drawn again
    results = tmp_path / "RESULTS.md"
    results.write_text("# Results\n\n<!-- BEGIN gates -->\nold\n<!-- END gates -->\n")
    again = gates.reproduce_gates(tmp_path, seeds=2, overrides=ITERATIONS, episodes=4, train=False, results=results)
    assert again == markdown and len(evaluations) == 3 and len(strips) == 1
    text = results.read_text()
    assert "old" not in text and markdown in text
    assert "`iap-mjx reproduce gates run.iterations=3 --seeds 2 --episodes 4 --frames 6 --out" in text
    assert (
        "![gates](experiments/gates/gates.png)" in text and "![gates-strip](experiments/gates/gates-strip.png)" in text
    )
    assert "IAP seed 0's checkpoint 3 on an unseen corridor" in text and "return 4.50" in text
    assert (tmp_path / "experiments" / "gates" / "gates-strip.png").stat().st_size > 0

    # fewer frames: drawn again
    gates.reproduce_gates(tmp_path, seeds=2, overrides=ITERATIONS, episodes=4, frames=3, train=False)
    assert strips[-1] == ("quadruped-gates-iap-seed0", "gates-strip.png", 3) and len(strips) == 2
    stored = json.loads((tmp_path / "gates.json").read_text())
    assert stored["parameters"] == {"IAP": 617, "blind": 617} and len(stored["rows"]) == 3
    assert (tmp_path / "gates.png").stat().st_size > 0

    # both seeds finished (the fixture's RUNS): means and seed-stds over two seeds, a paired line a seed
    shutil.rmtree(tmp_path / "quadruped-gates-iap-seed1")
    _run(tmp_path, "iap", 1)
    _run(tmp_path, "blind", 1)
    lines = gates.reproduce_gates(tmp_path, seeds=2, overrides=ITERATIONS, episodes=4, frames=3, train=False)
    lines = lines.splitlines()
    # IAP: returns 6 and 8, gates 1.5 and 2.5, contact steps 2 and 3, distance 6 and 8
    assert lines[2] == (
        "| IAP (`quadruped-gates-iap`) | 617 | 7.0 ± 1.0 | 2.00 ± 0.50 | 2.5 ± 0.5 | 0.25 ± 0.00 | 0.50 ± 0.00 | "
        "7.00 ± 1.00 | 2 of 2 | 3 | 3,000 |"
    )
    assert lines[3] == (
        "| blind (`quadruped-gates-blind`) | 617 | 3.5 ± 0.5 | 0.50 ± 0.00 | 2.5 ± 0.5 | 0.25 ± 0.00 | "
        "0.50 ± 0.00 | 3.50 ± 0.50 | 2 of 2 | 3 | 3,000 |"
    )
    # eyes closed: returns 4 and 6, gates 0.5 and 1.5; each seed's differences 2, 0, 2, 0
    assert lines[9] == "| IAP | 7.0 ± 1.0 | 5.0 ± 1.0 | 2.00 ± 0.50 | 1.00 ± 0.50 | +1.00, +1.00 |"
    assert lines[-2:] == [
        f"- IAP seed {seed}: gates passed per corridor, eyes open minus closed on the same 4 corridors: +1.00 "
        "(SE 0.58; +1.7 SE)."
        for seed in (0, 1)
    ]


def test_no_strip_until_iap_seed_0_has_finished(tmp_path, evaluations, strips):
    _run(tmp_path, "iap", 0, iterations=2)
    _run(tmp_path, "blind", 0)
    results = tmp_path / "RESULTS.md"
    markdown = gates.reproduce_gates(tmp_path, seeds=1, overrides=ITERATIONS, episodes=2, train=False, results=results)
    assert strips == [] and not (tmp_path / "gates-strip.png").exists()
    assert "| IAP (`quadruped-gates-iap`) | 617 | - | - | - | - | - | - | 0 of 1 | 2 | 2,000 |" in markdown
    assert "The strip: drawn once IAP seed 0 has finished." in results.read_text()


def test_export_copies_each_runs_newest_checkpoint(tmp_path, evaluations, strips, capsys):
    _run(tmp_path / "out", "iap", 0)
    _run(tmp_path / "out", "blind", 0, iterations=2)
    export = tmp_path / "pretrained"
    args = ["reproduce", "gates", *ITERATIONS, "--episodes", "2", "--report-only"]
    assert cli.main([*args, "--out", str(tmp_path / "out"), "--export", str(export)]) == 0
    assert "| IAP (`quadruped-gates-iap`) | 617 | 6.0 ± 0.0 |" in capsys.readouterr().out
    assert sorted(p.name for p in export.iterdir()) == ["quadruped-gates-blind-seed0", "quadruped-gates-iap-seed0"]
    assert checkpoint.latest_step(export / "quadruped-gates-iap-seed0") == 3
    assert checkpoint.latest_step(export / "quadruped-gates-blind-seed0") == 2
