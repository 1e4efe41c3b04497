"""The README's Python examples, executed as a user pastes them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parent.parent / "README.md"


def readme_block(after: str) -> str:
    """The first ```python block of the README after the line ``after``."""
    text = README.read_text()
    return text[text.index(after) :].split("```python\n", 1)[1].split("```", 1)[0]


def test_the_attention_example_selects_ten_distinct_patches_per_frame():
    namespace: dict = {}
    exec(readme_block("The attention layer alone:"), namespace)
    selection, images = namespace["selection"], namespace["images"]
    batch = images.shape[0]
    assert selection.indices.shape == (batch, 10) and selection.centres.shape == (batch, 10, 2)
    assert all(len(set(row.tolist())) == 10 for row in np.asarray(selection.indices))


def test_the_own_env_example_learns_to_reach_its_targets():
    """The point-mass example trains to near its targets. Standing still, an episode returns
    ``-50 |X - Y|`` for ``X``, ``Y`` uniform in ``[-1, 1]^2``: mean ``-50 * 1.0428`` (twice the
    unit square's mean distance, 0.5214) and std ``50 * sqrt(4/3 - 1.0428^2)``; the centre's
    evaluation averages ``run.eval_episodes`` of them. The untrained (zero) linear policy must
    sit within 4 of those stds of the mean, the trained one 4 above it."""
    namespace: dict = {}
    exec(readme_block("### Your own env"), namespace)
    result = namespace["result"]
    mean_distance = 2 * 0.521405
    still_mean = -50 * mean_distance
    still_std = 50 * math.sqrt(4 / 3 - mean_distance**2) / math.sqrt(result.config.run.eval_episodes)
    first, last = result.history[0]["eval_return"], result.history[-1]["eval_return"]
    assert abs(first - still_mean) < 4 * still_std, (first, still_mean, still_std)
    assert last > still_mean + 4 * still_std, (last, still_mean, still_std)
    assert len(result.history) == result.config.run.iterations


def test_the_own_policy_example_learns_on_the_same_env():
    """The README's own policy, named nowhere in the package, trained on the own-env example's
    point mass (its block run first, as a reader pastes them in order), must end as far above
    standing still as the linear policy's test asks."""
    namespace: dict = {}
    exec(readme_block("### Your own env"), namespace)
    exec(readme_block("### Your own policy"), namespace)
    result = namespace["result"]
    assert set(result.params) == {"w"}  # the README's policy, not the config's linear one
    still_mean = -50 * 2 * 0.521405
    still_std = 50 * math.sqrt(4 / 3 - (2 * 0.521405) ** 2) / math.sqrt(result.config.run.eval_episodes)
    assert result.history[-1]["eval_return"] > still_mean + 4 * still_std, result.history[-1]["eval_return"]
