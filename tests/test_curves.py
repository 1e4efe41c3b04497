"""Reward curves from a run's metrics.csv."""

from iap_mjx.viz import curves


def test_curve_from_metrics_csv(tmp_path):
    (tmp_path / "metrics.csv").write_text(
        "iteration,return_mean,return_max,return_min,eval_return\n"
        "1,1.0,2.0,0.5,1.5\n2,2.0,3.0,1.0,\n3,3.0,4.0,2.0,3.5\n")
    history = curves.read_history(tmp_path)
    assert [row["iteration"] for row in history] == [1.0, 2.0, 3.0]
    assert "eval_return" not in history[1] and history[2]["eval_return"] == 3.5
    path = curves.plot_reward_curve(history, tmp_path / "curve.png", title="t")
    assert path.read_bytes()[:4] == b"\x89PNG"
