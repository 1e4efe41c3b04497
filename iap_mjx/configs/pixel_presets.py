"""Presets that learn from pixels: Cheetah-Run at 100x100 RGB with IAP, its ablations, baselines.

``cheetah-run-pixels`` follows the paper's Cheetah-Run ablation (Figure 6): 100x100 RGB,
non-overlapping 4x4 patches (``L = 625``), the top 10 patch centres into an LSTM controller
(16 units, Tang et al.'s choice: one frame's patch centres carry no velocity, and cheetah's
reward is its speed), hybrid features ``(m, r) = (10, 5)``; one frame per 4 control steps
(action repeat 4). ``RESULTS.md`` (learning) compares it with a linear controller. The
variants change only the attention kernel: ``-relu``, ``-hybrid-M-R`` for the paper's four
``(m, r)`` pairs, ``-brute`` (explicit softmax with row normalisation: Tang et al.'s
AttentionAgent); ``-cnn`` replaces the whole policy with a small feed-forward CNN (baseline).
``cheetah-run-pixels-quick`` is the same policy on short episodes and a small population:
the README's first command, a few minutes on two cores.
"""

from __future__ import annotations

from iap_mjx.configs.presets import register
from iap_mjx.es.config import EnvConfig, ESConfig, PolicyConfig, RunConfig, TrainConfig

PIXELS = (("obs_mode", "pixels"), ("height", 100), ("width", 100))
ATTENTION = (("patch_size", 4), ("top_l", 10), ("d_qk", 4))
CONTROLLER = (("controller", "lstm"), ("hidden_sizes", (16,)))
KERNELS = {
    "relu": (("kernel", "relu"),),
    "hybrid-3-2": (("kernel", "hybrid"), ("m", 3), ("r", 2)),
    "hybrid-6-3": (("kernel", "hybrid"), ("m", 6), ("r", 3)),
    "hybrid-10-5": (("kernel", "hybrid"), ("m", 10), ("r", 5)),
    "hybrid-16-8": (("kernel", "hybrid"), ("m", 16), ("r", 8)),
    "brute": (("kernel", "brute"), ("row_normalize", True)),
}
# One frame (camera + attention + controller) per 4 control steps, as PlaNet/DrQ do on
# cheetah from pixels: the episode is still dm_control's 1000 steps and its return.
ACTION_REPEAT = 4
PIXEL_ES = ESConfig(population_size=64, sigma=0.05, learning_rate=0.02, weight_decay=0.005,
                    normalize_observations=False)


def pixel_config(policy: PolicyConfig, *, episode_length: int | None = None,
                 es: ESConfig = PIXEL_ES,
                 run: RunConfig = RunConfig(iterations=100, eval_episodes=4, checkpoint_every=5)
                 ) -> TrainConfig:
    """Cheetah-Run from 100x100 RGB with ``policy``, each frame's action held for
    ``ACTION_REPEAT`` control steps; ``episode_length`` in env steps (``None``: dm_control's
    1000 control steps)."""
    options = PIXELS + (("action_repeat", ACTION_REPEAT),)
    if episode_length is not None:
        options += (("episode_length", episode_length),)
    return TrainConfig(env=EnvConfig("cheetah-run", options), policy=policy, es=es, run=run)


def iap_policy(kernel: str) -> PolicyConfig:
    """The IAP policy with ``kernel`` (a key of :data:`KERNELS`)."""
    return PolicyConfig("iap", ATTENTION + KERNELS[kernel] + CONTROLLER)


register("cheetah-run-pixels",
         "cheetah-run from 100x100 RGB: IAP hybrid (10, 5) (the paper's pick), 4x4 patches, top 10 -> LSTM(16)",
         lambda: pixel_config(iap_policy("hybrid-10-5")))
for _name in KERNELS:
    if _name != "hybrid-10-5":
        register(f"cheetah-run-pixels-{_name}",
                 f"cheetah-run-pixels with the {_name} attention kernel (Figure 6 ablation)",
                 lambda _name=_name: pixel_config(iap_policy(_name)))
register("cheetah-run-pixels-cnn", "cheetah-run from 100x100 RGB with a small CNN policy (baseline)",
         lambda: pixel_config(PolicyConfig("cnn")))
register("cheetah-run-pixels-quick",
         "cheetah-run-pixels on 200-control-step episodes, population 16, 10 iterations: a few minutes",
         lambda: pixel_config(
             iap_policy("hybrid-10-5"), episode_length=200 // ACTION_REPEAT,
             es=ESConfig(population_size=16, sigma=0.05, learning_rate=0.02, normalize_observations=False),
             run=RunConfig(iterations=10, eval_episodes=2, checkpoint_every=5, chunk_size=16)))
