"""The trained policies that ship in ``pretrained/`` are run directories ``iap-mjx eval`` and
``iap-mjx video`` read: each holds one checkpoint with its config and metrics, and one is
evaluated for a few steps."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from iap_mjx import configs, es
from iap_mjx.es import checkpoint

PRETRAINED = Path(__file__).resolve().parent.parent / "pretrained"
RUNS = sorted(path.parent.parent for path in PRETRAINED.glob("*/*/checkpoints/*"))


def test_every_shipped_run_has_one_checkpoint_its_config_and_metrics():
    assert RUNS, f"no trained policy in {PRETRAINED}"
    for run in RUNS:
        assert len(list((run / checkpoint.CHECKPOINT_DIR).iterdir())) == 1, run
        assert (run / "config.json").exists() and (run / "metrics.csv").exists(), run
        config = configs.TrainConfig.from_dict(checkpoint.load_config(run))
        assert checkpoint.latest_step(run) <= config.run.iterations


@pytest.mark.slow
def test_a_shipped_dcs_policy_loads_and_evaluates_for_a_few_steps():
    run = next(run for run in RUNS if run.parent.name == "dcs")
    # small background frames and 5-step episodes: the trained policy, a quick program
    returns = es.evaluate_run(
        run, episodes=2, seed=0, overrides=("env.episode_length=5", "env.background_size=64", "env.background_frames=4")
    )
    assert returns.shape == (2,) and np.all(np.isfinite(returns)) and np.all(returns >= 0)


def started_from_a_low_level_file() -> list[Path]:
    """The shipped hierarchies trained from ``policy.low_level_init`` (a path relative to where
    they trained)."""
    started = [
        run
        for run in RUNS
        if "low_level_init" in dict(configs.TrainConfig.from_dict(checkpoint.load_config(run)).policy.options)
    ]
    assert started, "no shipped run started from a low level file"
    return started


def test_a_run_started_from_a_low_level_file_loads_from_any_folder(tmp_path, monkeypatch):
    """Such a run loads and takes an evaluation condition from another folder: its checkpoint,
    not the file, holds its parameters."""
    started = started_from_a_low_level_file()
    monkeypatch.chdir(tmp_path)
    result = es.load_run(started[0])
    stored = checkpoint.load_config(started[0])
    assert result.config.policy.options == tuple(
        (name, value)
        for name, value in configs.TrainConfig.from_dict(stored).policy.options
        if name != "low_level_init"
    )
    assert int(result.state.iteration) == checkpoint.latest_step(started[0])
    assert not np.allclose(result.params["low"]["w"], 0.0)
    closed = es.in_condition(result, ["policy.blind=true"])
    assert closed.policy.blind
    # one step of its policy function from an episode's initial state (the held command)
    import jax

    key = jax.random.PRNGKey(0)
    obs = jax.tree_util.tree_map(
        lambda leaf: np.zeros(leaf.shape, leaf.dtype), jax.eval_shape(result.env.reset, key).obs
    )
    action, state = result.policy_fn(result.params, obs, result.initial_policy_state(key))
    assert action.shape == (result.env.action_size,) and np.all(np.isfinite(action))
    assert jax.tree_util.tree_structure(state) == jax.tree_util.tree_structure(result.initial_policy_state(key))


def test_show_prints_such_a_run_from_any_folder_with_its_stored_config(tmp_path, monkeypatch, capsys):
    """``iap-mjx show RUN_DIR`` builds the run as it is loaded and prints the config it stored,
    the file its low level started from included."""

    from iap_mjx import cli

    run = started_from_a_low_level_file()[0]
    monkeypatch.chdir(tmp_path)
    assert cli.main(["show", str(run), "policy.blind=true"]) == 0
    view = json.loads(capsys.readouterr().out)
    stored = configs.TrainConfig.from_dict(checkpoint.load_config(run))
    assert configs.TrainConfig.from_dict(view["config"]) == configs.apply_overrides(stored, ["policy.blind=true"])
    assert view["policy"]["settings"]["blind"] is True
    assert view["policy"]["parameters"] == sum(view["policy"]["parameters_per_level"].values())


def test_eval_in_a_condition_that_resizes_the_policy_names_the_sizes_and_the_setting(capsys):
    """A CNN's parameters depend on the frame's size: evaluated on a taller frame, the shipped
    run fails before anything compiles, saying which sizes differ and which setting did it."""
    from iap_mjx import cli

    run = PRETRAINED / "quadruped" / "quadruped-walls-cnn-seed0"
    sizes = []
    for overrides in ([], ["env.height=48"]):  # the parameters as shipped, and as the condition builds them
        assert cli.main(["show", str(run), *overrides]) == 0
        sizes.append(json.loads(capsys.readouterr().out)["policy"]["parameters"])
    assert sizes[0] != sizes[1]
    assert cli.main(["eval", str(run), "env.height=48", "--episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert f"strategy_state.mean ({sizes[0]},) stored, ({sizes[1]},) built" in err and "env.height=48" in err
