"""The time of one policy forward pass, which Figures 1, 6 and 8 report beside their runs."""

from __future__ import annotations

import time

from iap_mjx import configs


def inference_seconds(config: configs.TrainConfig, *, passes: int = 100) -> float:
    """Mean wall time of one compiled policy forward pass on one rendered observation (the mean
    of ``passes`` passes after compiling)."""
    import jax

    from iap_mjx.es import make_env_and_policy

    env, policy = make_env_and_policy(config)
    key = jax.random.PRNGKey(0)
    obs = jax.jit(env.reset)(key).obs
    params = policy.init(key)
    policy_state = policy.initial_state(key)
    forward = jax.jit(policy.apply)
    jax.block_until_ready(forward(params, obs, policy_state))
    start = time.perf_counter()
    for _ in range(passes):
        out = forward(params, obs, policy_state)
    jax.block_until_ready(out)
    return (time.perf_counter() - start) / passes
