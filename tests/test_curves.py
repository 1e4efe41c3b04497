"""Reward curves from a run's history, as ``metrics.jsonl`` holds it."""

from iap_mjx.es.metrics_log import MetricsWriter, read_history
from iap_mjx.viz import curves


def test_curve_from_the_runs_history(tmp_path):
    writer = MetricsWriter(tmp_path, resume_from=None, tensorboard=False)
    for i, eval_return in ((1, 1.5), (2, None), (3, 3.5)):
        row = {"iteration": i, "return_mean": float(i), "return_max": i + 1.0, "return_min": i - 0.5}
        if eval_return is not None:
            row["eval_return"] = eval_return
        writer.write(row)
    writer.close()
    history = read_history(tmp_path)
    assert [row["iteration"] for row in history] == [1, 2, 3]
    assert "eval_return" not in history[1] and history[2]["eval_return"] == 3.5
    path = curves.plot_reward_curve(history, tmp_path / "curve.png", title="t")
    assert path.read_bytes()[:4] == b"\x89PNG"
