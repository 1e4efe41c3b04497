"""The host-side pieces of ``train`` that its end-to-end tests (``test_es_train.py``) exercise
only in passing: the sigma schedules' ends, the parameter count's wording, each iteration's
metrics row, when a run checkpoints or stops, and a checkpoint restored into a state of
other shapes. No program is compiled."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from iap_mjx.configs import ESConfig, RunConfig
from iap_mjx.es import bookkeeping, checkpoint
from iap_mjx.es.bookkeeping import checkpoint_due, metric_rows, past_time_limit
from iap_mjx.es.components import describe_parameters, make_sigma


@pytest.mark.parametrize("schedule", ["linear", "exponential"])
def test_a_sigma_schedule_runs_from_sigma_to_sigma_final_over_the_run(schedule):
    sigma = make_sigma(ESConfig(sigma=0.2, sigma_schedule=schedule, sigma_final=0.05), iterations=40)
    np.testing.assert_allclose([float(sigma(0)), float(sigma(40))], [0.2, 0.05], rtol=1e-6)
    assert 0.05 < float(sigma(20)) < 0.2
    assert make_sigma(ESConfig(sigma=0.2), iterations=40) == 0.2


def test_describe_parameters_names_each_level_of_a_policy_that_has_levels():
    class Levelled:
        def level_param_counts(self, params):
            return {"high": 489, "low": 384}

    parts = SimpleNamespace(num_dims=873, policy=Levelled(), template_params={})
    assert describe_parameters(parts) == "873 parameters (high 489, low 384)"
    assert describe_parameters(SimpleNamespace(num_dims=12, policy=object(), template_params={})) == "12 parameters"


def test_metric_rows_number_the_iterations_and_split_the_call_time():
    parts = SimpleNamespace(steps_per_iteration=100, simulated_steps_per_iteration=120, num_dims=7)
    metrics = {"return_mean": np.array([1.5, 2.5]), "nan_episodes": np.array([0, 3])}
    rows = metric_rows(parts, done=4, metrics=metrics, run_s=2.0, compile_s=5.0)
    assert [row["iteration"] for row in rows] == [5, 6]
    assert [row["env_steps"] for row in rows] == [500, 600]
    assert [row["return_mean"] for row in rows] == [1.5, 2.5] and rows[1]["nan_episodes"] == 3.0
    for row in rows:
        assert row["env_steps_per_s"] == 120 and row["run_s"] == 1.0
        assert row["compile_s"] == 5.0 and row["parameters"] == 7


def test_checkpoints_are_due_periodically_at_the_end_and_when_out_of_time():
    run = RunConfig(iterations=10, checkpoint_every=3)
    assert [done for done in range(1, 11) if checkpoint_due(run, done, False)] == [3, 6, 9, 10]
    assert checkpoint_due(run, 4, True)
    at_the_end_only = RunConfig(iterations=10, checkpoint_every=0)
    assert [done for done in range(1, 11) if checkpoint_due(at_the_end_only, done, False)] == [10]


def test_the_time_limit_counts_from_the_start_and_zero_means_none(monkeypatch):
    now = 1000.0
    monkeypatch.setattr(bookkeeping.time, "perf_counter", lambda: now)
    assert not past_time_limit(RunConfig(max_minutes=0), now - 1e6)
    assert not past_time_limit(RunConfig(max_minutes=1), now - 60)
    assert past_time_limit(RunConfig(max_minutes=1), now - 60.5)


def test_reading_a_checkpoint_logs_no_warning(tmp_path, caplog):
    """Orbax warns for every item of a checkpoint that a manager without its handler reads;
    a resume, an eval or a video of a run reads both items."""
    state = {"mean": np.arange(4.0), "step": np.array(2)}
    checkpoint.save(tmp_path, 2, state, {"a": 1})
    with caplog.at_level(logging.WARNING):
        assert checkpoint.latest_step(tmp_path) == 2
        assert checkpoint.load_config(tmp_path) == {"a": 1}
        step, restored = checkpoint.restore(tmp_path, state)
        assert checkpoint.stored_shapes(tmp_path, 2) == {"mean": (4,), "step": ()}
    assert step == 2 and np.array_equal(restored["mean"], state["mean"])
    assert not [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_a_checkpoint_restored_into_other_shapes_names_the_leaf_and_both_shapes(tmp_path):
    from flax import struct

    @struct.dataclass
    class State:
        iteration: np.ndarray
        strategy_state: dict

    saved = State(iteration=np.array(3), strategy_state={"mean": np.arange(5.0), "step": np.array(1)})
    checkpoint.save(tmp_path, 3, saved, {"a": 1})
    assert checkpoint.stored_shapes(tmp_path, 3) == {
        "iteration": (),
        "strategy_state.mean": (5,),
        "strategy_state.step": (),
    }
    step, restored = checkpoint.restore(tmp_path, saved)  # the same shapes restore
    assert step == 3 and np.array_equal(restored.strategy_state["mean"], np.arange(5.0))
    grown = State(iteration=np.array(0), strategy_state={"mean": np.zeros(6), "step": np.array(0)})
    with pytest.raises(
        checkpoint.ShapeMismatch,
        match=r"^checkpoint 3 in .* does not fit the run as built: strategy_state.mean \(5,\) stored, \(6,\) built \(",
    ):
        checkpoint.restore(tmp_path, grown)


def test_ties_stop_the_step_where_the_update_subtracts_a_baseline_or_pairs_cancel():
    assert bookkeeping.ties_stop_the_step(ESConfig())  # centred ranks
    assert bookkeeping.ties_stop_the_step(ESConfig(shaping="z_score"))
    assert bookkeeping.ties_stop_the_step(ESConfig(shaping="identity"))  # antithetic pairs cancel
    assert not bookkeeping.ties_stop_the_step(ESConfig(shaping="identity", antithetic=False))
    assert not bookkeeping.ties_stop_the_step(ESConfig(strategy="CMA_ES"))  # evosax's own update
