"""Reward curves from a run's history, as ``metrics.jsonl`` holds it."""

import numpy as np

from iap_mjx.es.metrics_log import MetricsWriter, read_history
from iap_mjx.viz import curves


def test_curve_from_the_runs_history(tmp_path, monkeypatch):
    writer = MetricsWriter(tmp_path, resume_from=0, tensorboard=False)
    for i, eval_return in ((1, 1.5), (2, None), (3, 3.5)):
        row = {"iteration": i, "return_mean": float(i), "return_max": i + 1.0, "return_min": i - 0.5}
        if eval_return is not None:
            row["eval_return"] = eval_return
        writer.write(row)
    writer.close()
    history = read_history(tmp_path)
    assert [row["iteration"] for row in history] == [1, 2, 3]
    assert "eval_return" not in history[1] and history[2]["eval_return"] == 3.5
    figures = []
    save_png = curves.save_png
    monkeypatch.setattr(curves, "save_png", lambda fig, path, **kw: (figures.append(fig), save_png(fig, path, **kw))[1])
    path = curves.plot_reward_curve(history, tmp_path / "curve.png", title="t")
    assert path.read_bytes()[:4] == b"\x89PNG"
    (ax,) = figures[0].axes
    mean, centre = ax.lines
    assert (mean.get_label(), centre.get_label()) == ("population mean", "centre (evaluation seeds)")
    np.testing.assert_array_equal(np.asarray(mean.get_xydata()), [[1, 1.0], [2, 2.0], [3, 3.0]])
    np.testing.assert_array_equal(np.asarray(centre.get_xydata()), [[1, 1.5], [3, 3.5]])  # iteration 2 not evaluated
    (band,) = ax.collections  # the min-max band: its outline runs through every min and max
    outline = {tuple(v) for v in band.get_paths()[0].vertices}
    assert {(1.0, 0.5), (2.0, 1.5), (3.0, 2.5), (1.0, 2.0), (2.0, 3.0), (3.0, 4.0)} <= outline
