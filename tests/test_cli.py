"""The ``iap-mjx`` command line: presets, errors before compiling, ``show``. Train -> eval end to
end is ``tests/test_first_run.py`` (the README's command, then ``iap-mjx eval`` on its run)."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

from iap_mjx import cli, configs, envs
from iap_mjx.es import results

CACHE = Path(__file__).resolve().parent.parent / ".jax_cache"


@pytest.fixture(autouse=True)
def test_cache(monkeypatch):
    monkeypatch.setenv("IAP_MJX_CACHE_DIR", str(CACHE))


def test_presets_lists_every_preset(capsys):
    assert cli.main(["presets"]) == 0
    out = capsys.readouterr().out
    for name in configs.names():
        assert name in out


def test_a_reader_that_leaves_early_ends_the_command_without_a_traceback():
    """``iap-mjx presets | head -1``: the pipe's reader is gone (here before the command writes,
    so the write always fails) and the command exits 1 with nothing on stderr."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        done = subprocess.run(
            [sys.executable, "-m", "iap_mjx.cli", "presets"], stdout=write_end, stderr=subprocess.PIPE
        )
    finally:
        os.close(write_end)
    assert done.returncode == 1 and done.stderr == b""


def test_unknown_preset_fails_listing_valid_ones(capsys):
    assert cli.main(["train", "no-such-preset"]) == 2
    err = capsys.readouterr().err
    assert "no-such-preset" in err and "cheetah-run-state" in err


def test_bad_override_fails_naming_the_field(capsys):
    assert cli.main(["train", "cheetah-run-state", "es.sigma=-1"]) == 2
    assert "es.sigma" in capsys.readouterr().err
    assert cli.main(["train", "cheetah-run-state", "policy.width=3"]) == 2
    err = capsys.readouterr().err
    assert "policy.options ['width'] do not fit policy 'linear'; valid: ['zero_init']" in err
    assert "run directory" not in err  # no run is named for a setting that cannot run


def test_misspelt_env_setting_fails_listing_the_valid_ones(capsys):
    assert cli.main(["train", "cheetah-run-state", "env.heigth=64", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "heigth" in err and "height" in err


def test_eval_of_missing_run_fails_and_creates_nothing(tmp_path, capsys):
    assert cli.main(["eval", str(tmp_path / "nothing")]) == 2
    assert "no checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "nothing").exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["eval", "x", "--episodes", "0"],
        ["video", "x", "--steps", "0"],
        ["reproduce", "fig1", "--seeds", "0"],
        ["train", "cheetah-run-state", "--process-id", "-1"],
    ],
)
def test_counts_below_one_are_refused_by_the_parser(argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    assert exit_.value.code == 2 and "must be >=" in capsys.readouterr().err


def test_interrupt_exits_130_with_resume_hint(monkeypatch, tmp_path, capsys):
    from iap_mjx import es

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(es, "train", interrupted)
    argv = ["train", "cheetah-run-state", "iterations=3", "es.sigma=0.1", "--run-dir", str(tmp_path / "a b")]
    assert cli.main(argv) == 130
    hint = capsys.readouterr().err.split("Resume with: ")[1].strip()
    # the hinted command parses, nothing left over, to the same preset, overrides and run directory
    words = shlex.split(hint)
    assert words[0] == "iap-mjx"
    again, unknown = cli.build_parser().parse_known_args(words[1:])
    assert unknown == [] and (again.preset, again.overrides, again.run_dir) == (
        "cheetah-run-state",
        ["iterations=3", "es.sigma=0.1"],
        str(tmp_path / "a b"),
    )


def test_train_refuses_a_run_directory_of_another_config_before_compiling_anything(monkeypatch, tmp_path, capsys):
    """A run directory holding another config's checkpoint (here a shipped cartpole run, trained
    again as cheetah) exits 2 naming what differs, before the video's background compile starts:
    a process leaving while XLA compiles in that thread aborts (exit status 134)."""
    import shutil

    from iap_mjx import es
    from iap_mjx.viz import artifacts

    def refused(*args, **kwargs):
        raise AssertionError("started after the run directory was refused")

    monkeypatch.setattr(artifacts, "compile_video_in_background", refused)
    monkeypatch.setattr(es, "train", refused)
    run_dir = tmp_path / "run"
    shutil.copytree(Path(__file__).resolve().parent.parent / "pretrained" / "dcs" / "cartpole-swingup-seed0", run_dir)
    assert cli.main(["train", "cheetah-run-pixels-quick", "--run-dir", str(run_dir)]) == 2
    err = capsys.readouterr().err
    assert "holds a checkpoint of a different config" in err and "env.name: checkpoint 'cartpole-swingup'" in err


@pytest.mark.parametrize("extra", [["--num-processes", "2"], ["--process-id", "1"]])
def test_multi_process_options_without_a_coordinator_are_refused(monkeypatch, tmp_path, capsys, extra):
    from iap_mjx import es

    monkeypatch.setattr(es, "train", lambda *args, **kwargs: pytest.fail("trained"))
    assert cli.main(["train", "cheetah-run-state", "--run-dir", str(tmp_path / "run"), *extra]) == 2
    assert "give --coordinator too" in capsys.readouterr().err


def test_a_command_stopping_early_waits_for_a_background_compile(monkeypatch, tmp_path, capsys):
    """Interrupted while the video compiles beside training, ``train`` returns only once that
    compile has ended (the process then exits cleanly: no daemon thread inside XLA)."""
    import concurrent.futures
    import threading

    from iap_mjx import es
    from iap_mjx.viz import artifacts

    future: concurrent.futures.Future = concurrent.futures.Future()
    done_at: list[float] = []

    def compile_later(*args, **kwargs):
        def finish():
            done_at.append(time.monotonic())
            future.set_result("program")

        threading.Timer(0.5, finish).start()
        return future

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(artifacts, "compile_video_in_background", compile_later)
    monkeypatch.setattr(es, "train", interrupted)
    assert cli.main(["train", "cheetah-run-pixels-quick", "--run-dir", str(tmp_path / "run")]) == 130
    assert future.done() and done_at and time.monotonic() >= done_at[0]
    assert "waiting for the video's background compile" in capsys.readouterr().err


def test_interrupted_reproduce_exits_130_saying_how_to_resume(monkeypatch, tmp_path, capsys):
    from iap_mjx.paper import table1

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(table1, "reproduce_table1", interrupted)
    code = cli.main(["reproduce", "table1", "--out", str(tmp_path)])
    captured = capsys.readouterr()
    assert code == 130 and captured.out == ""
    assert "the same command resumes" in captured.err


@pytest.mark.parametrize(
    "argv",
    [
        ["reproduce", "fig7", "--tasks", "cartpole-swingup"],  # table1's
        ["reproduce", "fig8", "--seeds", "2"],  # fig8 trains one seed per method
        ["reproduce", "table1", "--settings", "1x1"],  # table2's
        ["reproduce", "fig10", "run.iterations=3"],  # fig10 draws trained runs as they are
        ["reproduce", "table1", "--seed", "1"],  # table2's, not an abbreviation of --seeds
    ],
)
def test_reproduce_refuses_the_options_of_another_figure(argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.build_parser().parse_args(argv)
    assert exit_.value.code == 2 and "unrecognized arguments" in capsys.readouterr().err


@pytest.mark.parametrize("figure", ["fig1", "fig6", "fig7", "fig8", "table1", "fig11", "table2"])
@pytest.mark.parametrize("override", ["run.seed=1", "seed=1"])
def test_reproduce_refuses_a_seed_override_which_its_own_seeds_would_replace(
    figure, override, tmp_path, capsys, monkeypatch
):
    import iap_mjx.es

    def trains(config, **kwargs):
        raise AssertionError(f"{figure} trained with {override}")

    monkeypatch.setattr(iap_mjx.es, "train", trains)  # nothing may start
    out = tmp_path / "out"
    assert cli.main(["reproduce", figure, "es.sigma=0.1", override, "--out", str(out)]) == 2
    message = f"error: {figure} sets each run's seed itself (how many: seeds, --seeds on the command line, where it has them); remove {override}"
    assert message in capsys.readouterr().err
    assert not out.exists()  # refused before anything was trained or written


def test_an_unknown_option_is_refused_by_its_commands_parser_naming_the_options_it_takes(capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(["eval", "no-such-run", "--bogus", "1"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "iap-mjx eval: error: unrecognized arguments: --bogus" in err
    assert "usage: iap-mjx eval [-h] [--episodes EPISODES] [--seed SEED]" in err
    with pytest.raises(SystemExit):  # a figure's overrides would take the value: named with its option
        cli.main(["reproduce", "fig7", "--tasks", "cartpole-swingup", "run.iterations=3"])
    assert "error: unrecognized arguments: --tasks cartpole-swingup\n" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["eval", "run", "--episodes", "20", "env.distraction=none"], ["env.distraction=none"]),
        (
            ["eval", "run", "env.dynamic=true", "--seed", "3", "env.background_videos=val"],
            ["env.dynamic=true", "env.background_videos=val"],
        ),
        (
            ["train", "p", "--run-dir", "d", "run.iterations=3", "--no-progress", "es.sigma=0.1"],
            ["run.iterations=3", "es.sigma=0.1"],
        ),
        (["reproduce", "table1", "a=1", "--seeds", "2", "b=2", "--report-only", "a=3"], ["a=1", "b=2", "a=3"]),
    ],
)
def test_overrides_typed_after_an_option_join_the_others_in_the_order_typed(argv, expected):
    args, unknown = cli.parse(cli.build_parser(), argv)
    assert unknown == [] and args.overrides == expected


def test_an_evaluation_condition_typed_after_the_episodes_reaches_the_evaluation(monkeypatch, capsys):
    from iap_mjx import es

    seen = {}

    def evaluate(run_dir, *, episodes, seed, overrides):
        seen.update(run_dir=run_dir, episodes=episodes, overrides=overrides)
        raise FileNotFoundError("stop here")

    monkeypatch.setattr(es, "evaluate_run_episodes", evaluate)
    assert cli.main(["eval", "some-run", "--episodes", "20", "env.background_videos=val"]) == 2
    assert seen == {"run_dir": "some-run", "episodes": 20, "overrides": ("env.background_videos=val",)}
    # an unknown option among them is still refused, by the command's own parser, named alone
    with pytest.raises(SystemExit) as exit_:
        cli.main(["eval", "some-run", "--episodes", "20", "--bogus", "env.background_videos=val"])
    assert exit_.value.code == 2 and "error: unrecognized arguments: --bogus\n" in capsys.readouterr().err
    # a command without overrides takes none, wherever typed: fig10 draws trained runs as they are
    with pytest.raises(SystemExit) as exit_:
        cli.main(["reproduce", "fig10", "--frames", "4", "run.iterations=3"])
    assert exit_.value.code == 2 and "error: unrecognized arguments: run.iterations=3\n" in capsys.readouterr().err


def test_reproduce_parses_each_figures_options_and_overrides_before_or_after_them():
    parser = cli.build_parser()
    args = parser.parse_args(["reproduce", "table1", "--seeds", "2", "run.iterations=3", "--tasks", "a, b"])
    assert (args.figure, args.seeds, args.overrides, args.tasks) == ("table1", 2, ["run.iterations=3"], ("a", "b"))
    args = parser.parse_args(["reproduce", "table2", "--settings", "1x1,4x2", "--seed", "1"])
    assert (args.settings, args.seed, args.overrides, args.out) == (((1, 1), (4, 2)), 1, [], "results")
    args = parser.parse_args(["reproduce", "fig10", "--run-dirs", "x,y", "--frames", "4"])
    assert (args.run_dirs, args.frames) == (("x", "y"), 4)
    for empty in ("", "x,,y"):
        with pytest.raises(SystemExit) as exit_:
            parser.parse_args(["reproduce", "fig10", "--run-dirs", empty])
        assert exit_.value.code == 2


def test_show_prints_the_resolved_config_of_a_preset_and_of_a_run(tmp_path, capsys):
    overrides = ["es.population_size=8", "env.height=64", "env.width=64"]
    assert cli.main(["show", "walker-walk-pixels", *overrides]) == 0
    view = json.loads(capsys.readouterr().out)
    expected = configs.apply_overrides(configs.get("walker-walk-pixels"), overrides)
    assert configs.TrainConfig.from_dict(view["config"]) == expected
    settings = view["env"]["settings"]
    assert (settings["action_repeat"], settings["height"], settings["solver_iterations"]) == (2, 64, 8)
    assert view["env"]["observation_shape"] == [64, 64, 3] and view["env"]["env_steps_per_episode"] == 500
    assert view["policy"]["settings"]["attention"]["kernel"] == "hybrid"
    # W_Q, W_K (48 x 4 each) and the LSTM(16) on 10 patch centres into walker's 6 actions
    assert view["policy"]["parameters"] == 2 * 48 * 4 + (20 + 16) * 64 + 64 + 16 * 6 + 6
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text(json.dumps(expected.to_dict()))
    assert cli.main(["show", str(run_dir), "es.sigma=0.1"]) == 0
    again = configs.TrainConfig.from_dict(json.loads(capsys.readouterr().out)["config"])
    assert again == configs.apply_overrides(expected, ["es.sigma=0.1"])


@pytest.mark.parametrize(
    "argv, message",
    [
        (["show", "no-such-preset"], "no-such-preset"),
        (["show", "cheetah-run-state", "env.heigth=3"], "height"),
    ],
)
def test_show_fails_naming_the_problem(argv, message, tmp_path, capsys):
    assert cli.main(argv) == 2
    assert message in capsys.readouterr().err
    assert cli.main(["show", str(tmp_path)]) == 2
    assert "not a run directory" in capsys.readouterr().err


def test_eval_conditions_set_the_evaluated_env_and_nothing_else(monkeypatch):
    """``iap-mjx eval RUN env.k=v``: the run's config with the condition's env settings (the
    rest of the env, the policy and the ES as trained), validated before anything is built."""
    stored = configs.get("dcs-cartpole-swingup-quick").to_dict()
    monkeypatch.setattr(results.checkpoint, "load_config", lambda run_dir: stored)
    built = []

    class Built(Exception):
        pass

    def build(config, env=None, policy=None):
        built.append(config)
        raise Built

    monkeypatch.setattr(results, "build", build)
    with pytest.raises(Built):
        results.evaluate_run("run", episodes=3, overrides=("env.background_videos=val", "env.dynamic=true"))
    (config,) = built
    trained = configs.TrainConfig.from_dict(stored)
    env = dict(config.env.overrides)
    assert env["background_videos"] == "val" and env["dynamic"] is True
    unchanged = lambda pairs: {k: v for k, v in pairs if k not in ("background_videos", "dynamic")}  # noqa: E731
    assert unchanged(env.items()) == unchanged(trained.env.overrides) and len(unchanged(env.items())) >= 8
    assert config.policy == trained.policy and config.es == trained.es and config.run == trained.run
    with pytest.raises(Built):
        results.evaluate_run("run", overrides=("env.distraction=none",))
    assert envs.check_spec(built[-1].env).distraction_config() is None
    with pytest.raises(ValueError, match=r"set the env \(env.<field>=<value>\) or policy.blind=<value>"):
        results.evaluate_run("run", overrides=("es.sigma=0.1",))
    with pytest.raises(ValueError, match="background_videos = 'test': valid train, val"):
        results.evaluate_run("run", overrides=("env.background_videos=test",))
    assert len(built) == 2


def test_importing_the_command_line_imports_no_jax():
    """``main`` splits the CPU into devices and turns on constant hoisting before jax starts;
    a command module that imports jax (e.g. through ``iap_mjx.es``) at import time would
    leave one device, and a chaotic evaluation then ends otherwise than the tables'."""
    code = "import sys, iap_mjx.cli; print('jax' in sys.modules)"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "False"


def test_eval_defaults_to_the_tables_seed_and_says_so(monkeypatch, capsys):
    """``iap-mjx eval RUN`` draws the episodes the paper's tables drew (``EVAL_SEED``)."""
    import inspect

    import iap_mjx.es
    from iap_mjx.configs.training import EVAL_SEED

    for evaluate in (results.evaluate_run_episodes, results.evaluate_run):
        assert inspect.signature(evaluate).parameters["seed"].default == EVAL_SEED
    calls = []

    def evaluate(run_dir, **kwargs):
        calls.append(kwargs)
        raise ValueError("stop")

    monkeypatch.setattr(iap_mjx.es, "evaluate_run_episodes", evaluate)
    assert cli.main(["eval", "some-run"]) == 2 and calls[-1]["seed"] == EVAL_SEED
    assert cli.main(["eval", "some-run", "--seed", "7"]) == 2 and calls[-1]["seed"] == 7
    capsys.readouterr()
    with pytest.raises(SystemExit):
        cli.main(["eval", "-h"])
    assert f"default {EVAL_SEED}" in " ".join(capsys.readouterr().out.split())


def test_eval_refuses_a_condition_that_is_not_an_env_setting(tmp_path, capsys):
    assert cli.main(["eval", str(tmp_path), "run.seed=3"]) == 2
    assert "set the env (env.<field>=<value>) or policy.blind=<value>, got ['run.seed=3']" in capsys.readouterr().err
