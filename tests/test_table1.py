"""``iap-mjx reproduce table1``: bad input fails before anything compiles; finished runs are
evaluated once per condition (stored in the run directory); the table holds the paper's
baselines and the bar. Training and evaluation themselves are ``iap_mjx.paper.report_runs``'s and
``es.evaluate_run``'s (tested in test_fig1_fig6.py, test_es_train.py and test_cli.py); here
they are replaced by recorders so that the command's own logic runs in seconds."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fake_runs import fake_run

from iap_mjx import cli, configs, sections
from iap_mjx.configs.training import EVAL_SEED
from iap_mjx.es import checkpoint
from iap_mjx.es.metrics_log import EVAL_FILE
from iap_mjx.paper import table1


def test_bad_tasks_and_settings_fail_before_anything_runs(tmp_path, capsys):
    with pytest.raises(ValueError, match="choose from cheetah-run"):
        table1.reproduce_table1(tmp_path, tasks=("cartpole",))
    with pytest.raises(ValueError, match="heigth"):
        table1.reproduce_table1(tmp_path, overrides=("env.heigth=64",))
    with pytest.raises(ValueError, match="episodes"):
        table1.reproduce_table1(tmp_path, episodes=0)
    with pytest.raises(ValueError, match="section = 'Table 1' must be lower-case"):
        table1.reproduce_table1(tmp_path, section="Table 1")
    assert not list(tmp_path.iterdir())
    assert cli.main(["reproduce", "table1", "--tasks", "reacher", "--out", str(tmp_path)]) == 2
    assert "choose from" in capsys.readouterr().err
    assert cli.main(["reproduce", "table1", "--section", "Table 1", "--out", str(tmp_path)]) == 2
    assert "must be lower-case letters" in capsys.readouterr().err


def test_every_condition_is_a_valid_env_of_every_task():
    checked = table1.check(table1.TASKS, ())
    assert list(checked) == list(table1.TASKS)
    for task, config in checked.items():
        none = configs.overrides.apply_condition(config, table1.CONDITIONS["none"])
        assert "distraction" not in dict(none.env.overrides) or dict(none.env.overrides)["distraction"] in (
            None,
            "none",
        )
        held = dict(configs.overrides.apply_condition(config, table1.CONDITIONS["held-out"]).env.overrides)
        assert held["background_videos"] == "val" and held["distraction"] == "medium"


def test_finished_runs_are_evaluated_once_per_condition_and_reported(tmp_path, monkeypatch):
    config = configs.apply_overrides(configs.get("dcs-cartpole-swingup"), ("run.iterations=3",))
    fake_run(tmp_path / "dcs-cartpole-swingup-seed0", config, 3, [1.0, 2.0, 3.0])
    fake_run(tmp_path / "dcs-cartpole-swingup-seed1", config, 2, [1.0, 5.0, 0.0])  # unfinished
    calls = []

    def evaluate_run(run_dir, *, episodes, seed, overrides):
        calls.append((run_dir.name, tuple(overrides), episodes, seed))
        return np.full(episodes, 200.0 + 10 * len(overrides))

    from iap_mjx import es

    monkeypatch.setattr(es, "evaluate_run", evaluate_run)

    def report(**kwargs):
        return table1.reproduce_table1(
            tmp_path,
            seeds=2,
            overrides=("run.iterations=3",),
            episodes=4,
            train=False,
            tasks=("cartpole-swingup",),
            **kwargs,
        )

    markdown = report()
    assert sorted(call[1] for call in calls) == sorted(table1.CONDITIONS.values())
    assert {call[0] for call in calls} == {"dcs-cartpole-swingup-seed0"}  # the finished run only
    assert all(call[2] == 4 and call[3] == EVAL_SEED for call in calls)
    row = next(line for line in markdown.splitlines() if line.startswith("| cartpole-swingup"))
    assert (
        "| 196.0 | 167.0 | 200.0 ± 0.0 | 200.0 | 210.0 ± 0.0 |" in row and "| 1 of 2 | 3 | 24,000 |" in row
    )  # 3,000 actions x 8
    assert "0 of 0 finished tasks" in markdown  # a task counts once all its seeds are finished
    stored = json.loads((tmp_path / "dcs-cartpole-swingup-seed0" / EVAL_FILE).read_text())
    assert len(stored) == 4
    report()
    assert len(calls) == 4  # read back, not evaluated again
    eval_path = tmp_path / "dcs-cartpole-swingup-seed0" / EVAL_FILE
    short = json.loads(eval_path.read_text())
    key = next(k for k in short if k.startswith("none@"))
    short[key] = short[key][:2]  # as an evaluate_run that returned one device's share stored it
    eval_path.write_text(json.dumps(short))
    report()
    assert len(calls) == 5 and calls[-1][1] == table1.CONDITIONS["none"]
    assert len(json.loads(eval_path.read_text())[key]) == 4
    assert (tmp_path / "table1.png").stat().st_size > 0
    results = tmp_path / "RESULTS.md"
    results.write_text(
        "# Results\n\n<!-- BEGIN table1 -->\nold\n<!-- END table1 -->\n\n<!-- BEGIN other -->\nkept\n<!-- END other -->\n"
    )
    report(results=results)
    text = results.read_text()
    assert "old" not in text and "kept" in text and row in text and "![table1](experiments/table1/table1.png)" in text
    assert "`iap-mjx reproduce table1 run.iterations=3 --seeds 2 --episodes 4" in text
    published = tmp_path / "experiments" / "table1" / "table1.png"  # tracked, unlike the output folder
    assert published.read_bytes() == (tmp_path / "table1.png").read_bytes()
    assert json.loads((tmp_path / "table1.json").read_text())[0]["conditions"]["none"] == [210.0] * 4
    # a second setting's table beside the first: its own section, json and figure
    report(results=results, section="table1-second")
    second = sections.read_section(results, "table1-second")
    assert second is not None and second.startswith("## Table 1 (`table1-second`): the Distracting Control Suite")
    assert "--section table1-second --out" in second and row in second
    assert "![table1-second](experiments/table1-second/table1-second.png)" in second
    assert (
        sections.read_section(results, "table1")
        == text.split("<!-- BEGIN table1 -->\n")[1].split("\n<!-- END table1 -->")[0]
    )
    assert (tmp_path / "table1-second.json").exists() and (tmp_path / "experiments" / "table1-second").is_dir()


def test_the_bar_counts_tasks_at_or_above_the_better_baseline():
    def rows(task, value):
        return [
            {
                "task": task,
                "parameters": 1,
                "seed": s,
                "curve": [value],
                "seconds": 1.0,
                "iterations": 1,
                "env_steps": 10,
                "control_steps": 40,
                "finished": True,
                "conditions": {name: [value] for name in table1.CONDITIONS},
            }
            for s in range(3)
        ]

    markdown = table1.table(
        rows("cartpole-swingup", 196.0) + rows("walker-walk", 110.0) + rows("reacher-easy", 109.0), seeds=3
    )
    assert "2 of 3 finished tasks" in markdown  # walker's 110 is below QT-Opt's 111
    six = [r for task in table1.TASKS for r in rows(task, 170.0)]
    assert "Six-task mean: 170.0" in table1.table(six, seeds=3)


def test_wall_clock_per_run_is_the_finished_runs_mean():
    def row(seed, seconds, finished):
        return {
            "task": "walker-walk",
            "parameters": 1,
            "seed": seed,
            "curve": [1.0],
            "seconds": seconds,
            "iterations": 100 if finished else 50,
            "env_steps": 10,
            "control_steps": 40,
            "finished": finished,
            "conditions": {name: [1.0] for name in table1.CONDITIONS} if finished else {},
        }

    line = lambda markdown: next(x for x in markdown.splitlines() if x.startswith("| walker-walk"))  # noqa: E731
    assert "| 40 | 7380 | 1 |" in line(table1.table([row(0, 7380.0, True), row(1, 9000.0, False)], seeds=3))
    assert "| 40 | - | 1 |" in line(table1.table([row(1, 9000.0, False)], seeds=3))


def test_export_copies_the_newest_checkpoint_and_the_run_files(tmp_path, monkeypatch):
    config = configs.apply_overrides(configs.get("dcs-cartpole-swingup"), ("run.iterations=3",))
    run = tmp_path / "out" / "dcs-cartpole-swingup-seed0"
    fake_run(run, config, 2, [1.0, 2.0])
    checkpoint.save(run, 1, {"x": np.ones(2)}, config.to_dict())  # an older step: not exported
    export = tmp_path / "pretrained"
    table1.reproduce_table1(
        tmp_path / "out",
        seeds=1,
        overrides=("run.iterations=3",),
        train=False,
        tasks=("cartpole-swingup",),
        export=export,
    )
    copied = export / "cartpole-swingup-seed0"
    assert sorted(p.name for p in (copied / checkpoint.CHECKPOINT_DIR).iterdir()) == ["2"]
    assert checkpoint.latest_step(copied) == 2
    assert (copied / "metrics.jsonl").read_text() == (run / "metrics.jsonl").read_text()
    assert configs.TrainConfig.from_dict(checkpoint.load_config(copied)) == config
    step, state = checkpoint.restore(copied, {"x": np.ones(2)})
    assert step == 2 and np.array_equal(state["x"], np.zeros(2))
    # the run goes on: the next export replaces the copied checkpoint with the newer one
    checkpoint.save(run, 3, {"x": np.full(2, 3.0)}, config.to_dict())
    assert checkpoint.export_latest(run, copied) == 3
    assert sorted(p.name for p in (copied / checkpoint.CHECKPOINT_DIR).iterdir()) == ["3"]
    assert np.array_equal(checkpoint.restore(copied, {"x": np.ones(2)})[1]["x"], np.full(2, 3.0))
    assert checkpoint.export_latest(tmp_path / "nothing", tmp_path / "dest") is None
    assert not (tmp_path / "dest").exists()


def test_cnn_baseline_is_reported_beside_the_iap_runs_with_both_parameter_counts(tmp_path, monkeypatch):
    """``--policy cnn``: its own run directories and section, the IAP runs of the same tasks
    read beside it (never trained by it), and each policy's parameter count, the sum of its
    layers' shapes."""
    overrides = ("run.iterations=2",)
    for policy, returns in (("iap", [150.0, 160.0]), ("cnn", [100.0, 120.0])):
        config = configs.apply_overrides(configs.get(table1.preset("cartpole-swingup", policy)), overrides)
        fake_run(tmp_path / f"{table1.preset('cartpole-swingup', policy)}-seed0", config, 2, returns)

    def evaluate_run(run_dir, *, episodes, seed, overrides):
        return np.full(episodes, 100.0 if "-cnn-" in run_dir.name else 160.0) + 10 * len(overrides)

    from iap_mjx import es

    monkeypatch.setattr(es, "evaluate_run", evaluate_run)
    results = tmp_path / "RESULTS.md"
    markdown = table1.reproduce_table1(
        tmp_path,
        seeds=1,
        overrides=overrides,
        episodes=2,
        train=False,
        tasks=("cartpole-swingup",),
        results=results,
        policy="cnn",
        export=tmp_path / "pretrained",
    )
    iap_count = 2 * 12 * 4 + (20 + 16) * 64 + 64 + 16 + 1  # W_Q, W_K (12 -> 4); LSTM(16) on 10 centres
    cnn_count = (27 * 8 + 8) + (72 * 16 + 16) + (144 * 16 + 16) + (320 * 16 + 16) + (16 + 16) * 64 + 64 + 16 + 1
    row = next(line for line in markdown.splitlines() if line.startswith("| cartpole-swingup"))
    assert row == (
        f"| cartpole-swingup | {iap_count:,} | 160.0 ± 0.0 | 170.0 ± 0.0 | {cnn_count:,} | 100.0 ± 0.0 | "
        "110.0 ± 0.0 | 110.0 ± 0.0 | 110.0 ± 0.0 | 1 and 1 of 1 | 2 |"
    )
    assert (tmp_path / "table1-cnn.png").stat().st_size > 0 and not (tmp_path / "table1.png").exists()
    assert [r["policy"] for r in json.loads((tmp_path / "table1-cnn.json").read_text())] == ["cnn"]
    text = results.read_text()
    assert "<!-- BEGIN table1-cnn -->" in text and "--policy cnn" in text and row in text
    assert "--tasks cartpole-swingup " in text  # the section's command trains only the tasks reported
    assert sorted(p.name for p in (tmp_path / "pretrained").iterdir()) == ["cartpole-swingup-cnn-seed0"]
    with pytest.raises(ValueError, match="policy 'rnn': choose from iap, cnn"):
        table1.reproduce_table1(tmp_path, policy="rnn")


def test_cnn_baseline_reads_the_iap_runs_with_the_setting_they_trained_with(tmp_path, monkeypatch):
    """A second setting whose IAP runs took an option the CNN cannot take
    (``policy.with_patches``): the CNN table's IAP column is those runs, counted as trained
    (its parameters from their own config), not ``dcs-<task>`` with the CNN's overrides."""
    stack = ("run.iterations=2", "env.frame_stack=2")
    iap = configs.apply_overrides(configs.get("dcs-cartpole-swingup"), (*stack, "policy.with_patches=true"))
    cnn = configs.apply_overrides(configs.get("dcs-cartpole-swingup-cnn"), stack)
    fake_run(tmp_path / "dcs-cartpole-swingup-seed0", iap, 2, [150.0, 160.0])
    fake_run(tmp_path / "dcs-cartpole-swingup-cnn-seed0", cnn, 2, [100.0, 120.0])
    from iap_mjx import es

    monkeypatch.setattr(es, "evaluate_run", lambda run_dir, *, episodes, seed, overrides: np.full(episodes, 1.0))
    markdown = table1.reproduce_table1(
        tmp_path, seeds=1, overrides=stack, episodes=2, train=False, tasks=("cartpole-swingup",), policy="cnn"
    )
    row = next(line for line in markdown.splitlines() if line.startswith("| cartpole-swingup"))
    with_patches, without = (
        table1.parameters(iap),
        table1.parameters(configs.apply_overrides(configs.get("dcs-cartpole-swingup"), stack)),
    )
    assert with_patches - without == 64 * 10 * 2 * 2 * 6  # the LSTM's 4 x 16 gates see 10 stacked 2x2 RGB patches more
    assert row.startswith(f"| cartpole-swingup | {with_patches:,} | 1.0 ± 0.0 |"), row


def test_the_parameter_count_is_the_policy_built_for_the_observation_training_sees():
    """A second stacked frame widens only the patches' rows of W_Q and W_K (the paper's
    ``d_qk`` columns each): ``2 * patch_size^2 * 3 * d_qk`` more parameters (a count built for a
    fixed RGB frame would not see the stack)."""
    config = configs.get("dcs-cartpole-swingup")
    options = dict(config.policy.options)
    stacked = configs.apply_overrides(config, ("env.frame_stack=2",))
    added = table1.parameters(stacked) - table1.parameters(config)
    assert added == 2 * options["patch_size"] ** 2 * 3 * options["d_qk"]
