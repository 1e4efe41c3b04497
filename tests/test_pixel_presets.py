"""Every pixel preset builds its env and policy (no compile) and its policy is the one named."""

import jax
import pytest

from iap_mjx import configs, envs, policies
from iap_mjx.policies.base import param_count

PIXEL_PRESETS = [name for name in configs.names() if "pixels" in name]


@pytest.mark.parametrize("name", PIXEL_PRESETS)
def test_pixel_preset_builds_env_and_policy(name):
    config = configs.get(name)
    env = envs.make(config.env.name, **dict(config.env.overrides))
    assert env.observation_shape == (100, 100, 3)
    policy = policies.make(config.policy.kind, env.observation_shape, env.action_size,
                           **dict(config.policy.options))
    params = jax.eval_shape(policy.init, jax.random.PRNGKey(0))
    if config.policy.kind == "iap":
        assert policy.layer.num_patches == 625 and policy.attention.top_l == 10
        # W_Q, W_K (48 x 4 each) and a 16-unit LSTM on 10 centres, read out to the actions.
        lstm = (20 + 16) * 4 * 16 + 4 * 16 + 16 * env.action_size + env.action_size
        assert param_count(params) == 2 * 48 * 4 + lstm
        expected_kernel = name.removeprefix("cheetah-run-pixels").lstrip("-").split("-")[0] or "hybrid"
        assert policy.attention.kernel == {"quick": "hybrid"}.get(expected_kernel, expected_kernel)


def test_paper_feature_settings():
    for suffix, (m, r) in {"hybrid-3-2": (3, 2), "hybrid-6-3": (6, 3), "hybrid-16-8": (16, 8)}.items():
        options = dict(configs.get(f"cheetah-run-pixels-{suffix}").policy.options)
        assert (options["m"], options["r"]) == (m, r)
    options = dict(configs.get("cheetah-run-pixels").policy.options)
    assert (options["kernel"], options["m"], options["r"]) == ("hybrid", 10, 5)
    assert dict(configs.get("cheetah-run-pixels-brute").policy.options)["row_normalize"] is True
