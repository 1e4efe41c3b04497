"""The MSE figures: the command writes both PNGs, and their Monte Carlo points agree with the curves."""

import numpy as np

from iap_mjx import cli
from iap_mjx.viz import mse_figures


def test_figures_command_writes_both_pngs(tmp_path):
    assert cli.main(["figures", "mse", "--out", str(tmp_path), "--draws", "2000"]) == 0
    for name in ("figure3_mse.png", "figure4_mse_slices.png"):
        data = (tmp_path / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000


def test_plotted_monte_carlo_points_follow_the_closed_forms():
    """Every plotted estimator at the slice, within 5 standard errors of its closed form."""
    theta = np.array([0.3, 1.5, 2.8])
    mc = mse_figures.monte_carlo(mse_figures.SLICE_LENGTH, theta, draws=50_000)
    closed = mse_figures.closed_forms(np.full_like(theta, mse_figures.SLICE_LENGTH), theta)
    for kind in mse_figures.ESTIMATORS:
        mse, stderr = mc[kind]
        assert np.all(np.abs(mse - closed[kind]) <= 5 * stderr + 1e-6), (kind, mse, closed[kind], stderr)
