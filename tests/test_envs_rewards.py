"""``iap_mjx.envs.rewards.tolerance`` against dm_control's numpy ``rewards.tolerance``."""

import itertools

import numpy as np
import pytest
from dm_control.utils import rewards as dm_rewards

from iap_mjx.envs import rewards

BOUNDS = [(0.0, 0.0), (-1.0, 2.0), (10.0, float("inf")), (float("-inf"), 0.5)]
MARGINS = [0.0, 0.5, 2.0, 10.0]


@pytest.mark.parametrize("sigmoid", rewards.SIGMOIDS)
def test_tolerance_matches_dm_control(sigmoid):
    x = np.random.default_rng(0).normal(scale=8.0, size=4096).astype(np.float32)
    # Points on and just beside the bounds and margins, where the branches switch (not
    # denormals: XLA flushes them to zero).
    edges = np.array([0.0, -1.0, 2.0, 10.0, 0.5, -0.5, 2.5, 4.0, 20.0, -3.0], np.float32)
    x = np.concatenate([x, edges, edges + np.float32(1e-5), edges - np.float32(1e-5)])
    values_at_margin = [0.0, 0.1, 0.5, 0.9] if sigmoid in ("cosine", "linear", "quadratic") else [0.1, 0.5, 0.9]
    fn = rewards.tolerance
    for bounds, margin, value in itertools.product(BOUNDS, MARGINS, values_at_margin):
        expected = dm_rewards.tolerance(x.astype(np.float64), bounds, margin, sigmoid, value)
        got = np.asarray(fn(x, bounds, margin, sigmoid, value))
        np.testing.assert_allclose(got, expected, rtol=2e-6, atol=2e-6, err_msg=f"{bounds} {margin} {value}")


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(bounds=(1.0, 0.0)),
        dict(margin=-1.0),
        dict(margin=1.0, sigmoid="gaussian", value_at_margin=0.0),
        dict(margin=1.0, sigmoid="linear", value_at_margin=1.0),
        dict(margin=1.0, sigmoid="nope"),
    ],
)
def test_tolerance_rejects_what_dm_control_rejects(kwargs):
    with pytest.raises(ValueError):
        dm_rewards.tolerance(np.zeros(3), **kwargs)
    with pytest.raises(ValueError):
        rewards.tolerance(np.zeros(3, np.float32), **kwargs)
