"""The ``iap-mjx`` command line: presets, errors before compiling, ``show``. Train -> eval end to
end is ``tests/test_first_run.py`` (the README's command, then ``iap-mjx eval`` on its run)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from iap_mjx import cli, configs

CACHE = Path(__file__).resolve().parent.parent / ".jax_cache"


@pytest.fixture(autouse=True)
def test_cache(monkeypatch):
    monkeypatch.setenv("IAP_MJX_CACHE_DIR", str(CACHE))


def test_presets_lists_every_preset(capsys):
    assert cli.main(["presets"]) == 0
    out = capsys.readouterr().out
    for name in configs.names():
        assert name in out


def test_unknown_preset_fails_listing_valid_ones(capsys):
    assert cli.main(["train", "no-such-preset"]) == 2
    err = capsys.readouterr().err
    assert "no-such-preset" in err and "cheetah-run-state" in err


def test_bad_override_fails_naming_the_field(capsys):
    assert cli.main(["train", "cheetah-run-state", "es.sigma=-1"]) == 2
    assert "es.sigma" in capsys.readouterr().err
    assert cli.main(["train", "cheetah-run-state", "policy.width=3"]) == 2
    assert "policy.options" in capsys.readouterr().err


def test_misspelt_env_setting_fails_listing_the_valid_ones(capsys):
    assert cli.main(["train", "cheetah-run-state", "env.heigth=64", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "heigth" in err and "height" in err


def test_eval_of_missing_run_fails_and_creates_nothing(tmp_path, capsys):
    assert cli.main(["eval", str(tmp_path / "nothing")]) == 2
    assert "no checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "nothing").exists()


@pytest.mark.parametrize("argv", [["eval", "x", "--episodes", "0"], ["video", "x", "--steps", "0"],
                                  ["reproduce", "fig1", "--seeds", "0"],
                                  ["train", "cheetah-run-state", "--process-id", "-1"]])
def test_counts_below_one_are_refused_by_the_parser(argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    assert exit_.value.code == 2 and "must be >=" in capsys.readouterr().err


def test_interrupt_exits_130_with_resume_hint(monkeypatch, tmp_path, capsys):
    from iap_mjx import es

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(es, "train", interrupted)
    code = cli.main(["train", "cheetah-run-state", "iterations=3", "--run-dir", str(tmp_path)])
    assert code == 130
    assert f"--run-dir {tmp_path}" in capsys.readouterr().err


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


@pytest.mark.parametrize("argv, message", [
    (["show", "no-such-preset"], "no-such-preset"),
    (["show", "cheetah-run-state", "env.heigth=3"], "height"),
])
def test_show_fails_naming_the_problem(argv, message, tmp_path, capsys):
    assert cli.main(argv) == 2
    assert message in capsys.readouterr().err
    assert cli.main(["show", str(tmp_path)]) == 2
    assert "not a run directory" in capsys.readouterr().err
