"""The reproduce command: bad input fails before anything compiles; the table reads its rows."""

import numpy as np
import pytest

from iap_mjx import cli
from iap_mjx.paper import fig1_fig6, report_runs


def test_unknown_figure_and_bad_override_fail_fast(capsys):
    with pytest.raises(ValueError, match="valid: fig6, fig1"):
        fig1_fig6.reproduce_fig1_fig6("fig9", "/tmp/unused")
    assert cli.main(["reproduce", "fig6", "es.population_size=7"]) == 2
    assert "es.population_size" in capsys.readouterr().err


def test_table_reports_mean_and_std_over_seeds():
    rows = [
        {
            "variant": "IAP",
            "preset": "cheetah-run-pixels",
            "inference_s": 0.0021,
            "returns": [10.0, 20.0, 30.0],
            "train_wall_s": 12.0,
            "iterations": 5,
        }
    ]
    line = fig1_fig6.table(rows).splitlines()[-1]
    assert "| 2.100 |" in line and "20.0 ± 8.2" in line and "| 3 | 5 |" in line


def test_figure_has_bars_crosses_and_one_curve_per_variant(tmp_path):
    rows = [
        {
            "variant": name,
            "preset": name,
            "inference_s": seconds,
            "returns": [5.0, 7.0],
            "curves": [[1.0, 3.0, 5.0], [2.0, 7.0]],
            "train_wall_s": 1.0,
            "iterations": 2,
        }
        for name, seconds in (("IAP", 0.002), ("Brute", 0.01))
    ]
    bars, curves, crosses = fig1_fig6.figure(rows, title="t").axes  # the bars' twin axis (made last) holds the crosses
    assert [patch.get_height() for patch in bars.patches] == [0.002, 0.01]
    np.testing.assert_allclose(np.asarray(crosses.lines[0].get_ydata(), dtype=float), [6.0, 6.0])
    assert [line.get_label() for line in curves.lines] == ["IAP", "Brute"]
    np.testing.assert_allclose(curves.lines[0].get_ydata(), [1.5, 5.0])  # cut to the shortest seed
    assert fig1_fig6.plot(rows, tmp_path / "fig.png", title="t").stat().st_size > 0


def test_eval_episodes_zero_is_refused_before_training():
    with pytest.raises(ValueError, match="run.eval_episodes"):
        fig1_fig6.reproduce_fig1_fig6("fig1", "/tmp/unused", overrides=("run.eval_episodes=0",))


def test_misspelt_env_setting_is_refused_before_training(tmp_path):
    with pytest.raises(ValueError, match="heigth"):
        fig1_fig6.reproduce_fig1_fig6("fig1", tmp_path, overrides=("env.heigth=64",))
    assert not list(tmp_path.iterdir())


def test_report_only_reads_rows_up_to_the_last_checkpoint_and_trains_nothing(tmp_path):
    from iap_mjx import configs
    from iap_mjx.es import checkpoint
    from iap_mjx.es.metrics_log import MetricsWriter

    config = configs.get("cheetah-run-pixels")
    run_dir = tmp_path / "cheetah-run-pixels-seed0"
    assert report_runs.trained_curve(config, 0, run_dir, train=False) is None  # nothing there yet
    writer = MetricsWriter(run_dir, 0, tensorboard=False)
    for i in range(1, 5):  # iteration 4 ran but the run was killed before its checkpoint
        writer.write({"iteration": i, "eval_return": 10.0 * i, "run_s": 2.0, "compile_s": 30.0})
    checkpoint.save(run_dir, 3, {"x": np.zeros(2)}, config.to_dict())
    curve, seconds = report_runs.trained_curve(config, 0, run_dir, train=False)
    assert curve == [10.0, 20.0, 30.0] and seconds == 3 * 2.0 + 30.0
    with pytest.raises(ValueError, match="no runs of fig1"):
        fig1_fig6.reproduce_fig1_fig6("fig1", tmp_path / "empty", train=False)
