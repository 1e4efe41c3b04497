"""``iap-mjx reproduce fig11``: bad input fails before anything compiles; finished runs are
evaluated once each on fresh courses (stored in the run directory) and reported with their
course statistics, parameter counts and the issue's bars; unfinished runs are read as far as
they got; exports copy the runs. Training and evaluation are ``iap_mjx.paper.report_runs``'s and
``es.evaluate_run_episodes``'s (tested in test_fig1_fig6.py, test_es_train.py and
test_quadruped_presets.py); here runs are written by hand and the evaluation is a recorder."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fake_runs import fake_run

from iap_mjx import cli, configs
from iap_mjx.configs.training import EVAL_SEED
from iap_mjx.es import checkpoint
from iap_mjx.es.metrics_log import EVAL_FILE
from iap_mjx.paper import fig11
from iap_mjx.paper.evaluations import EYES_CLOSED_OVERRIDES

ITERATIONS = ("run.iterations=3",)
POLICIES_RUN = ("iap", "cnn", "blind")
# (policy, seed): the evaluation's mean return and walls passed per episode - 0.5 (below)
RUNS = {
    ("iap", 0): (20.0, 1.0),
    ("iap", 1): (24.0, 2.0),
    ("cnn", 0): (24.0, 1.0),
    ("cnn", 1): (22.0, 2.0),
    ("blind", 0): (8.0, 0.0),
    ("blind", 1): (12.0, 0.0),
}


def _run(out, policy, seed, iterations=3):
    preset = f"quadruped-walls-{policy}"
    config = configs.apply_overrides(configs.get(preset), ITERATIONS)
    fake_run(out / f"{preset}-seed{seed}", config, iterations, [float(i) for i in range(1, iterations + 1)])


@pytest.fixture
def evaluations(monkeypatch):
    """Recorded calls; run (policy, seed) of ``RUNS`` gives per episode returns ``base -+ 2``,
    walls passed ``w + 1, w`` alternately, one fall in four, ``3 + seed`` wall contacts and
    ``base / 2`` metres; with its eyes closed (``policy.blind=true``) ``base - 4 - seed``
    and ``w - seed``; on another iteration's episodes (``episodes_of``, recorded as a fifth
    entry), ``base + 100``."""
    calls = []

    def evaluate_run_episodes(run_dir, *, episodes, seed, overrides=(), episodes_of=None):
        call = (run_dir.name, episodes, seed, tuple(overrides))
        calls.append(call if episodes_of is None else (*call, episodes_of))
        policy, run_seed = run_dir.name.split("-")[2], int(run_dir.name[-1])
        base, walls = RUNS[policy, run_seed]
        base += 0.0 if episodes_of is None else 100.0
        if tuple(overrides) == EYES_CLOSED_OVERRIDES:
            base, walls = base - 4.0 - run_seed, walls - run_seed
        alternate = np.arange(episodes) % 2
        return {
            "return": base - 2.0 + 4.0 * alternate,
            "walls_passed": walls + 1.0 - alternate,
            "fell_off": (np.arange(episodes) % 4 == 3).astype(float),
            "wall_contacts": np.full(episodes, 3.0 + run_seed),
            "distance": np.full(episodes, base / 2),
        }

    from iap_mjx import es

    monkeypatch.setattr(es, "evaluate_run_episodes", evaluate_run_episodes)
    return calls


def test_bad_input_fails_before_anything_runs(tmp_path, capsys):
    with pytest.raises(ValueError, match="heigth"):
        fig11.reproduce_fig11(tmp_path, overrides=("env.heigth=64",))
    with pytest.raises(ValueError, match="run.eval_episodes"):
        fig11.reproduce_fig11(tmp_path, overrides=("run.eval_episodes=0",))
    with pytest.raises(ValueError, match="episodes"):
        fig11.reproduce_fig11(tmp_path, episodes=0)
    with pytest.raises(ValueError, match="seeds"):
        fig11.reproduce_fig11(tmp_path, seeds=0)
    with pytest.raises(ValueError, match="section = 'Fig 11' must be lower-case letters"):
        fig11.reproduce_fig11(tmp_path, section="Fig 11")
    with pytest.raises(ValueError, match="courses_of must be an int >= 0"):
        fig11.reproduce_fig11(tmp_path, courses_of=-1)
    assert not list(tmp_path.iterdir())
    assert cli.main(["reproduce", "fig11", "policy.kernl=relu", "--out", str(tmp_path)]) == 2
    assert "kernl" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["reproduce", "fig11", "--courses-of", "-1", "--out", str(tmp_path)])
    assert "--courses-of: must be >= 0, got -1" in capsys.readouterr().err


def test_finished_runs_are_evaluated_once_and_reported_with_the_bars(tmp_path, evaluations):
    _run(tmp_path, "iap", 0)
    _run(tmp_path, "iap", 1)
    _run(tmp_path, "cnn", 0)
    _run(tmp_path, "cnn", 1, iterations=2)  # unfinished: read as far as it got, not evaluated
    _run(tmp_path, "blind", 0, iterations=2)  # blind seed 1: no run yet
    markdown = fig11.reproduce_fig11(tmp_path, seeds=2, overrides=ITERATIONS, episodes=4, train=False)
    assert sorted(evaluations) == [
        (f"quadruped-walls-{policy}-seed{seed}", 4, EVAL_SEED, condition)
        for policy, seed in (("cnn", 0), ("iap", 0), ("iap", 1))
        for condition in ((), ("policy.blind=true",))
    ]
    lines = markdown.splitlines()
    assert lines[2] == (
        "| IAP (`quadruped-walls-iap`) | 873 | 22.0 ± 2.0 | 2.00 ± 0.50 | 0.25 ± 0.00 | 3.5 ± 0.5 | "
        "11.00 ± 1.00 | 2 of 2 | 3 | 3,000 |"
    )
    assert lines[3] == (
        "| CNN (`quadruped-walls-cnn`) | 7,269 | 24.0 ± 0.0 | 1.50 ± 0.00 | 0.25 ± 0.00 | 3.0 ± 0.0 | "
        "12.00 ± 0.00 | 1 of 2 | 3 | 3,000 |"
    )
    assert lines[4] == "| blind (`quadruped-walls-blind`) | 873 | - | - | - | - | - | 0 of 2 | 2 | 2,000 |"
    # the seeing runs with their eyes closed: IAP seeds 0 and 1 lose 4 and 5 in return, 0 and 1 walls
    assert lines[9:13] == [
        "|---|---:|---:|---:|---:|---|",
        "| IAP | 22.0 ± 2.0 | 17.5 ± 1.5 | 2.00 ± 0.50 | 1.50 ± 0.00 | +0.00, +1.00 |",
        "| CNN | 24.0 ± 0.0 | 20.0 ± 0.0 | 1.50 ± 0.00 | 1.50 ± 0.00 | +0.00 |",
        "",
    ]
    assert lines[-1] == (
        "Bars: not decided yet (3 of 6 runs finished). Parameters: CNN 7,269, IAP 873 (8.3x; bar: >= 5x)."
    )
    stored = json.loads((tmp_path / "quadruped-walls-iap-seed1" / EVAL_FILE).read_text())
    assert stored["course@3x4s2021"] == {
        "return": [22.0, 26.0, 22.0, 26.0],
        "walls_passed": [3.0, 2.0, 3.0, 2.0],
        "fell_off": [0.0, 0.0, 0.0, 1.0],
        "wall_contacts": [4.0] * 4,
        "distance": [12.0] * 4,
    }
    assert stored["course-eyes-closed@3x4s2021"]["walls_passed"] == [2.0, 1.0, 2.0, 1.0]
    assert fig11.reproduce_fig11(tmp_path, seeds=2, overrides=ITERATIONS, episodes=4, train=False) == markdown
    assert len(evaluations) == 6  # read back from eval.json, not evaluated again

    _run(tmp_path, "cnn", 1)
    _run(tmp_path, "blind", 0)
    _run(tmp_path, "blind", 1)
    results = tmp_path / "RESULTS.md"
    results.write_text(
        "# Results\n\n<!-- BEGIN fig11 -->\nold\n<!-- END fig11 -->\n\n<!-- BEGIN other -->\nkept\n<!-- END other -->\n"
    )
    markdown = fig11.reproduce_fig11(tmp_path, seeds=2, overrides=ITERATIONS, episodes=4, train=False, results=results)
    assert len(evaluations) == 10  # the blind runs are not evaluated with their eyes closed: they have none
    assert markdown.splitlines()[-3:] == [
        "IAP against CNN: final return 22.0 ± 2.0 against 23.0 ± 1.0 (bar: IAP's mean >= the CNN's mean minus its "
        "seed-std, 22.0), with 8.3x fewer parameters (873 against 7,269; bar: >= 5x): met.",
        "IAP above blind in walls passed per episode: 2.00 ± 0.50 against 0.50 ± 0.00 (bar, 'clearly': the mean minus "
        "its seed-std above blind's mean plus its seed-std, 0.50): met.",
        "CNN above blind in walls passed per episode: 2.00 ± 0.50 against 0.50 ± 0.00 (bar, 'clearly': the mean minus "
        "its seed-std above blind's mean plus its seed-std, 0.50): met.",
    ]
    text = results.read_text()
    assert "old" not in text and "kept" in text and markdown in text and "![fig11](experiments/fig11/fig11.png)" in text
    assert "`iap-mjx reproduce fig11 run.iterations=3 --seeds 2 --episodes 4" in text
    stored = json.loads((tmp_path / "fig11.json").read_text())
    assert stored["parameters"] == {"IAP": 873, "CNN": 7269, "blind": 873}
    assert stored["summaries"]["blind"]["return"] == [8.0, 12.0] and len(stored["rows"]) == 6
    assert (tmp_path / "fig11.png").stat().st_size > 0


def test_bars_need_the_parameter_ratio_and_a_clear_margin_over_blind():
    def summary(parameters, returns, walls):
        return {"parameters": parameters, "finished": len(returns), "return": returns, "walls_passed": walls}

    blind = summary(873, [5.0, 5.0], [0.5, 1.5])  # walls 1.0 ± 0.5: the margin is 1.5
    lines = fig11.bars(
        {"IAP": summary(873, [30.0, 30.0], [2.0, 3.0]), "CNN": summary(4000, [20.0, 20.0], [1.5, 2.5]), "blind": blind},
        seeds=2,
    )
    assert lines[0].endswith("with 4.6x fewer parameters (873 against 4,000; bar: >= 5x): not met.")
    assert lines[1].endswith(": met.") and lines[2].endswith(": not met.")  # 2.5 - 0.5 > 1.5; 2.0 - 0.5 is not
    below = fig11.bars(
        {"IAP": summary(873, [18.0, 20.0], [2.0, 3.0]), "CNN": summary(7269, [20.0, 22.0], [2.0, 3.0]), "blind": blind},
        seeds=2,
    )
    assert below[0].endswith(
        "(bar: IAP's mean >= the CNN's mean minus its seed-std, 20.0), with 8.3x fewer "
        "parameters (873 against 7,269; bar: >= 5x): not met."
    )  # 19.0 < 20.0


def test_export_copies_each_runs_newest_checkpoint(tmp_path, evaluations, capsys):
    _run(tmp_path / "out", "iap", 0)
    _run(tmp_path / "out", "blind", 0, iterations=2)
    export = tmp_path / "pretrained"
    assert (
        cli.main(
            [
                "reproduce",
                "fig11",
                *ITERATIONS,
                "--seeds",
                "1",
                "--episodes",
                "2",
                "--report-only",
                "--out",
                str(tmp_path / "out"),
                "--export",
                str(export),
            ]
        )
        == 0
    )
    assert "| IAP (`quadruped-walls-iap`) | 873 | 20.0 ± 0.0 |" in capsys.readouterr().out
    assert evaluations == [
        ("quadruped-walls-iap-seed0", 2, EVAL_SEED, condition) for condition in ((), EYES_CLOSED_OVERRIDES)
    ]
    assert sorted(p.name for p in export.iterdir()) == ["quadruped-walls-blind-seed0", "quadruped-walls-iap-seed0"]
    assert checkpoint.latest_step(export / "quadruped-walls-iap-seed0") == 3
    assert checkpoint.latest_step(export / "quadruped-walls-blind-seed0") == 2
    copied = configs.TrainConfig.from_dict(checkpoint.load_config(export / "quadruped-walls-iap-seed0"))
    assert copied == configs.apply_overrides(configs.get("quadruped-walls-iap"), ITERATIONS)


def test_a_second_experiment_writes_its_own_section_beside_the_first(tmp_path, evaluations):
    """``--section fig11-turn``: its own RESULTS.md section and experiments/ folder, the
    command that rewrites it; the default section stays as it was."""
    for policy in POLICIES_RUN:
        _run(tmp_path / "out", policy, 0)
    results = tmp_path / "RESULTS.md"
    results.write_text("# Results\n\n<!-- BEGIN fig11 -->\nfirst\n<!-- END fig11 -->\n")
    args = ["reproduce", "fig11", *ITERATIONS, "--seeds", "1", "--episodes", "2", "--report-only"]
    paths = ["--out", str(tmp_path / "out"), "--results", str(results)]
    assert cli.main([*args, *paths, "--section", "fig11-turn"]) == 0
    text = results.read_text()
    assert "<!-- BEGIN fig11 -->\nfirst\n<!-- END fig11 -->" in text
    assert "<!-- BEGIN fig11-turn -->\n## Figure 11 (`fig11-turn`): the quadruped" in text
    assert "![fig11-turn](experiments/fig11-turn/fig11.png)" in text and "--section fig11-turn --out" in text
    assert (tmp_path / "experiments" / "fig11-turn" / "fig11.png").stat().st_size > 0
    assert not (tmp_path / "experiments" / "fig11").exists()


def test_courses_of_another_iteration_plays_the_runs_on_that_reports_courses(tmp_path, evaluations):
    """``--courses-of 2``: every finished run (3 iterations) is evaluated on iteration 2's
    episodes, eyes open and closed, stored under its own ``eval.json`` keys beside the run's own
    courses, reported in ``fig11-courses-of-2.json`` and a section whose command says so; the
    report on the runs' own courses is left as it was. ``--courses-of 3``, the checkpoint's own
    iteration, is the plain report."""
    out = tmp_path / "out"
    for policy in POLICIES_RUN:
        _run(out, policy, 0)
    args = ["reproduce", "fig11", *ITERATIONS, "--seeds", "1", "--episodes", "2", "--report-only", "--out", str(out)]
    assert cli.main(args) == 0
    own = (out / "fig11.json").read_text()
    assert len(evaluations) == 5 and all(len(call) == 4 for call in evaluations)

    results = tmp_path / "RESULTS.md"
    results.write_text("# Results\n")
    section = ["--results", str(results), "--section", "fig11-on-2"]
    assert cli.main([*args, "--courses-of", "2", *section]) == 0
    assert sorted(evaluations[5:]) == [
        (f"quadruped-walls-{policy}-seed0", 2, EVAL_SEED, condition, 2)
        for policy, conditions in (
            ("blind", ((),)),
            ("cnn", ((), EYES_CLOSED_OVERRIDES)),
            ("iap", ((), EYES_CLOSED_OVERRIDES)),
        )
        for condition in conditions
    ]
    stored = json.loads((out / "quadruped-walls-iap-seed0" / EVAL_FILE).read_text())
    assert stored["course-of2@3x2s2021"]["return"] == [118.0, 122.0]  # base 20 + 100, -+ 2
    assert stored["course@3x2s2021"]["return"] == [18.0, 22.0]
    assert stored["course-eyes-closed-of2@3x2s2021"]["return"] == [114.0, 118.0]
    assert (out / "fig11.json").read_text() == own
    other = json.loads((out / "fig11-courses-of-2.json").read_text())
    assert other["summaries"]["IAP"]["return"] == [120.0] and other["summaries"]["blind"]["return"] == [108.0]
    assert (out / "fig11-courses-of-2.png").stat().st_size > 0
    text = results.read_text()
    assert "--courses-of 2 --section fig11-on-2 --out" in text
    assert "keys of seed 2021 and iteration 2: the courses of a 2-iteration checkpoint's report" in text
    assert "![fig11-on-2](experiments/fig11-on-2/fig11-courses-of-2.png)" in text

    assert cli.main([*args, "--courses-of", "2"]) == 0
    assert cli.main([*args, "--courses-of", "3"]) == 0
    assert len(evaluations) == 10  # both read back from eval.json: iteration 3's courses are the runs' own
    plain = json.loads((out / "fig11-courses-of-3.json").read_text())
    assert plain["summaries"] == json.loads(own)["summaries"]  # the runs' own courses: the plain report's numbers
