"""``iap-mjx reproduce table2``: a bad (patch size, stride) fails before anything compiles, naming
the setting and the valid ones; each setting trains with its overrides and the same budget (the
preset's own setting in the preset's run, shared with fig11); the table reports the maximum
episode return, L, the finished runs' walls passed on unseen courses and the command. Training
is ``iap_mjx.paper.report_runs``'s (tested in test_fig1_fig6.py) and evaluation ``iap_mjx.es``'s
(``evaluate_run``: test_es_train.py, test_cli.py, test_pretrained.py); here runs are written by
hand, training is a recorder and evaluation a stand-in."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fake_runs import fake_run

from iap_mjx import cli, configs
from iap_mjx.paper import report_runs, table2

ITERATIONS = ("run.iterations=3",)
VALID = (
    "(1, 1), (2, 1), (2, 2), (3, 1), (4, 1), (4, 2), (4, 4), (5, 1), (6, 1), (6, 2), (7, 1), (8, 1), (8, 2), "
    "(8, 4), (8, 8)"
)


WALLS = {"table2-p1-s1": 0.5, "table2-p2-s2": 1.5, "quadruped-walls-iap": 1.0, "table2-p4-s2": 0.25}  # any seed


@pytest.fixture
def evaluations(monkeypatch):
    """Recorded calls; run ``name`` passes ``WALLS[name] -+ 0.5`` walls on alternate courses
    and returns 3 m a wall passed, 1 m more on odd courses."""
    calls = []

    def evaluate_run_episodes(run_dir, *, episodes, seed, overrides=(), episodes_of=None):
        assert episodes_of is None  # every run is evaluated on its own checkpoint's episodes
        calls.append((run_dir.name, episodes, seed, tuple(overrides)))
        alternate = np.arange(episodes) % 2
        walls = WALLS[run_dir.name.rsplit("-", 1)[0]] - 0.5 + alternate
        return {
            "return": 3.0 * walls + alternate,
            "walls_passed": walls,
            "fell_off": np.zeros(episodes),
            "wall_contacts": np.zeros(episodes),
            "distance": 3.0 * walls,
        }

    from iap_mjx import es

    monkeypatch.setattr(es, "evaluate_run_episodes", evaluate_run_episodes)
    return calls


def _run(out, setting, population_max, iterations=3):
    own = setting == (4, 4)
    config = configs.apply_overrides(
        configs.get(table2.PRESET), ITERATIONS + (() if own else table2.setting_overrides(*setting))
    )
    name = "quadruped-walls-iap-seed0" if own else f"table2-p{setting[0]}-s{setting[1]}-seed0"
    fake_run(out / name, config, iterations, [float(i) for i in range(1, iterations + 1)], population_max)


def test_bad_settings_fail_before_anything_runs(tmp_path, capsys):
    with pytest.raises(ValueError) as error:
        table2.reproduce_table2(tmp_path, settings=((1, 1), (3, 3)))
    assert str(error.value) == (
        "table2 setting (patch size 3, stride 3): patches of size 3 with stride 3 do not tile the image: (width 32 - "
        "patch_size) is not a multiple of the stride; choose sizes with (size - patch_size) % stride == 0. Valid "
        f"(patch size, stride) on the 24x32 camera with top_l = 10, stride <= patch size <= 8: {VALID}"
    )
    with pytest.raises(ValueError, match=r"setting \(patch size 8, stride 8\): L = 12 patches, fewer than top_l = 20"):
        table2.reproduce_table2(tmp_path, settings=((8, 8),), overrides=("policy.top_l=20",))
    with pytest.raises(ValueError, match="remove policy.stride=2"):
        table2.reproduce_table2(tmp_path, overrides=("policy.stride=2",))
    with pytest.raises(ValueError, match="distinct"):
        table2.reproduce_table2(tmp_path, settings=((1, 1), (1, 1)))
    with pytest.raises(ValueError, match="distinct"):
        table2.reproduce_table2(tmp_path, settings=((1.0, 1),))
    with pytest.raises(ValueError, match="heigth"):
        table2.reproduce_table2(tmp_path, overrides=("env.heigth=48",))
    with pytest.raises(ValueError, match="episodes must be an int >= 1, got 0"):
        table2.reproduce_table2(tmp_path, episodes=0)
    assert not list(tmp_path.iterdir())
    assert cli.main(["reproduce", "table2", "--settings", "1x1,3x3", "--out", str(tmp_path)]) == 2
    assert "patch size 3, stride 3" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:
        cli.main(["reproduce", "table2", "--settings", "1by1", "--out", str(tmp_path)])
    assert exit_.value.code == 2 and "PATCHxSTRIDE" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_each_setting_trains_with_its_overrides_and_the_same_budget(tmp_path, monkeypatch, evaluations):
    trained = []

    def trained_curve(config, seed, run_dir, *, train=True):
        options = dict(config.policy.options)
        trained.append((run_dir.name, options["patch_size"], options.get("stride"), config.run.iterations, seed))
        fake_run(run_dir, config, 2, [1.0, 2.0])
        return [1.0, 2.0], 10.0

    monkeypatch.setattr(report_runs, "trained_curve", trained_curve)
    table2.reproduce_table2(tmp_path, seed=1, overrides=("run.iterations=2",))
    assert trained == [
        ("table2-p1-s1-seed1", 1, 1, 2, 1),
        ("table2-p2-s2-seed1", 2, 2, 2, 1),
        ("quadruped-walls-iap-seed1", 4, None, 2, 1),
        ("table2-p4-s2-seed1", 4, 2, 2, 1),
    ]


def test_table_reports_maximum_returns_unseen_courses_patches_and_commands(tmp_path, capsys, evaluations):
    _run(tmp_path, (1, 1), [4.0, 12.0, 8.0])
    _run(tmp_path, (2, 2), [3.0, 6.0], iterations=2)  # unfinished; (4, 2) has no run yet
    _run(tmp_path, (4, 4), [5.0, 9.0, 7.0])
    markdown = table2.reproduce_table2(tmp_path, overrides=ITERATIONS, train=False, episodes=4)
    lines = markdown.splitlines()
    # parameters: 873 at 4x4 (worked out in test_hierarchical), less W_Q's and W_K's 4 columns
    # for each of the 3 * (16 - p^2) inputs a smaller patch drops
    p1, p2 = (873 - 2 * 4 * 3 * (16 - p * p) for p in (1, 2))
    assert lines[2:5] == [
        f"| 1 | 1 | 768 | {p1} | 12.0 | 3.0 | 0.50 | 2.00 | 3 | 36 | `iap-mjx train quadruped-walls-iap "
        f"run.iterations=3 policy.patch_size=1 policy.stride=1 run.seed=0 --run-dir {tmp_path}/table2-p1-s1-seed0` |",
        f"| 2 | 2 | 192 | {p2} | 6.0 | 2.0 |  |  | 2 (running) | 34 | `iap-mjx train quadruped-walls-iap "
        f"run.iterations=3 policy.patch_size=2 policy.stride=2 run.seed=0 --run-dir {tmp_path}/table2-p2-s2-seed0` |",
        f"| 4 | 4 | 48 | 873 | 9.0 | 3.0 | 1.00 | 3.50 | 3 | 36 | `iap-mjx train quadruped-walls-iap "
        f"run.iterations=3 run.seed=0 --run-dir {tmp_path}/quadruped-walls-iap-seed0` |",
    ]
    assert lines[-1] == "Best setting: not decided yet (2 of 4 settings finished)."
    # finished runs only, on the evaluation seed's courses in the training condition
    assert evaluations == [("table2-p1-s1-seed0", 4, 2021, ()), ("quadruped-walls-iap-seed0", 4, 2021, ())]
    _run(tmp_path, (2, 2), [3.0, 6.0, 1.0])
    _run(tmp_path, (4, 2), [1.0, 20.0, 3.0])
    results = tmp_path / "RESULTS.md"
    argv = [
        "reproduce",
        "table2",
        *ITERATIONS,
        "--settings",
        "1x1,2x2,4x4,4x2",
        "--episodes",
        "4",
        "--report-only",
        "--out",
        str(tmp_path),
        "--results",
        str(results),
    ]
    assert cli.main(argv) == 0
    markdown = capsys.readouterr().out.rstrip("\n")
    assert markdown.splitlines()[5].startswith("| 4 | 2 | 165 | 873 | 20.0 | 3.0 | 0.25 | 1.25 | 3 | 36 |")
    assert markdown.splitlines()[-1] == (
        "Best setting by the paper's metric: patch size 4, stride 2 (max return 20.0); the paper's best had the "
        "most patches, here patch size 1, stride 1 (L = 768, max return 12.0). Most walls passed on unseen "
        "courses: patch size 2, stride 2 (1.50 a course, 4 courses)."
    )
    # evaluated once each, then read back from the run directories
    assert [call[0] for call in evaluations[2:]] == ["table2-p2-s2-seed0", "table2-p4-s2-seed0"]
    text = results.read_text()
    assert "<!-- BEGIN table2 -->" in text and markdown in text and "![table2](experiments/table2/table2.png)" in text
    assert (
        f"`iap-mjx reproduce table2 run.iterations=3 --settings 1x1,2x2,4x4,4x2 --seed 0 --episodes 4 --out {tmp_path}"
        in text
    )
    stored = json.loads((tmp_path / "table2.json").read_text())
    assert [row["population_max"] for row in stored][3] == [1.0, 20.0, 3.0]
    assert stored[1]["course"]["walls_passed"] == [1.0, 2.0, 1.0, 2.0]
    assert (tmp_path / "table2.png").stat().st_size > 0


def test_a_saturated_maximum_is_reported_as_a_tie(tmp_path, evaluations):
    """The course's length caps the return: settings that both reach it tie by the paper's metric."""
    for setting in table2.SETTINGS:
        # a few cm past the course's end either way: tied at the table's precision
        best = {(1, 1): [4.0, 10.004, 10.0], (4, 4): [4.0, 6.0, 10.0147]}
        _run(tmp_path, setting, best.get(setting, [4.0, 6.0, 9.94]))
    markdown = table2.reproduce_table2(tmp_path, overrides=ITERATIONS, train=False, episodes=2)
    assert markdown.splitlines()[-1].startswith(
        "Best setting by the paper's metric: patch size 1, stride 1 and patch size 4, stride 4 (max return 10.0, tied);"
    )


def test_export_copies_each_runs_newest_checkpoint_finished_or_not(tmp_path, capsys, evaluations):
    """``--export``: every setting's run directory, the preset's own (shared with fig11) under
    its own name, so that a session can ship unfinished runs and the next resume them."""
    from iap_mjx.es import checkpoint

    _run(tmp_path / "out", (1, 1), [4.0, 12.0, 8.0])
    _run(tmp_path / "out", (2, 2), [3.0, 6.0], iterations=2)
    _run(tmp_path / "out", (4, 4), [5.0, 9.0, 7.0])
    export = tmp_path / "pretrained"
    argv = [
        "reproduce",
        "table2",
        *ITERATIONS,
        "--report-only",
        "--out",
        str(tmp_path / "out"),
        "--export",
        str(export),
    ]
    assert cli.main(argv) == 0
    capsys.readouterr()
    assert sorted(p.name for p in export.iterdir()) == [
        "quadruped-walls-iap-seed0",
        "table2-p1-s1-seed0",
        "table2-p2-s2-seed0",
    ]
    assert checkpoint.latest_step(export / "table2-p2-s2-seed0") == 2
    copied = configs.TrainConfig.from_dict(checkpoint.load_config(export / "table2-p1-s1-seed0"))
    assert copied == configs.apply_overrides(configs.get(table2.PRESET), ITERATIONS + table2.setting_overrides(1, 1))
