"""The named presets' rows: :class:`Preset` and the general rows (``iap-mjx presets`` lists
every row, with ``dcs_presets``' and ``quadruped_presets``'; ``iap_mjx.configs.catalog`` looks
them up by name).

A row (:class:`Preset`) names a task, a policy, and the ES and loop settings; its ``config()``
is a validated :class:`TrainConfig`. The helpers below (``pixels``, ``iap``) spell
the settings the rows share once, so each row says only what makes it different.

The pixel presets follow the paper's Cheetah-Run setting (Figure 6): 100x100 RGB,
non-overlapping 4x4 patches (``L = 625``), the top 10 patch centres into an LSTM controller
(16 units, Tang et al.'s choice: one frame's patch centres carry no velocity), hybrid features
``(m, r) = (10, 5)``; one frame per ``ACTION_REPEAT[task]`` control steps, as PlaNet and DrQ
do from pixels (the episode is still dm_control's 1000 control steps and its return).
``RESULTS.md`` has what they reach.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from iap_mjx.configs.training import EnvSpec, ESConfig, PolicySpec, RunConfig, TrainConfig

Options = tuple[tuple[str, Any], ...]

ACTION_REPEAT = {
    "cheetah-run": 4,
    "walker-walk": 2,
    "cartpole-swingup": 8,
    "ball_in_cup-catch": 4,
    "reacher-easy": 4,
    "finger-spin": 2,
}
"""Control steps per frame from pixels, per task (PlaNet/DrQ's settings): one entry for each
of the suite's tasks (``configs.distraction.TASKS``; ``tests/test_dcs_presets.py`` holds them
equal)."""

FIG6_KERNELS: dict[str, Options] = {
    "relu": (("kernel", "relu"),),
    "hybrid-3-2": (("kernel", "hybrid"), ("m", 3), ("r", 2)),
    "hybrid-6-3": (("kernel", "hybrid"), ("m", 6), ("r", 3)),
    "hybrid-10-5": (("kernel", "hybrid"), ("m", 10), ("r", 5)),
    "hybrid-16-8": (("kernel", "hybrid"), ("m", 16), ("r", 8)),
    "brute": (("kernel", "brute"), ("row_normalize", True)),
}
"""The attention kernels of the paper's Figure 6 ablation (``brute``: explicit softmax with
row normalisation, Tang et al.'s AttentionAgent)."""


@dataclasses.dataclass(frozen=True)
class Preset:
    """One row of the table.

    Attributes:
      name, description: what ``iap-mjx presets`` shows.
      env, env_options: a registry env name and its ``EnvConfig`` overrides.
      policy, policy_options: a policy kind and its options.
      es, run: the evolution strategy and the training loop.
    """

    name: str
    description: str
    env: str
    policy: str
    env_options: Options = ()
    policy_options: Options = ()
    es: ESConfig = ESConfig()
    run: RunConfig = RunConfig()

    def config(self) -> TrainConfig:
        """The validated ``TrainConfig`` this row stands for."""
        return TrainConfig(
            env=EnvSpec(self.env, self.env_options),
            policy=PolicySpec(self.policy, self.policy_options),
            es=self.es,
            run=self.run,
        )


def pixels(task: str, height: int = 100, width: int = 100) -> Options:
    """Env options for ``height`` x ``width`` RGB frames, one per ``ACTION_REPEAT[task]`` control
    steps (dm_control's 1000 control steps per episode)."""
    return (("obs_mode", "pixels"), ("height", height), ("width", width), ("action_repeat", ACTION_REPEAT[task]))


def iap(kernel: str = "hybrid-10-5", *, patch_size: int = 4) -> Options:
    """Policy options of the IAP policy: ``patch_size`` square patches (4x4 at 100x100), top 10,
    ``kernel`` (a key of :data:`FIG6_KERNELS`), a 16-unit LSTM controller."""
    return (
        (("patch_size", patch_size), ("top_l", 10), ("d_qk", 4))
        + FIG6_KERNELS[kernel]
        + (("controller", "lstm"), ("hidden_sizes", (16,)))
    )


STATE_ES = ESConfig(population_size=64, sigma=0.03, learning_rate=0.02, weight_decay=0.005)
PIXEL_ES = ESConfig(
    population_size=64, sigma=0.05, learning_rate=0.02, weight_decay=0.005, normalize_observations=False
)
PIXEL_RUN = RunConfig(iterations=100, eval_episodes=4, checkpoint_every=5)

PRESETS: tuple[Preset, ...] = (
    Preset(
        "cheetah-run-state",
        "cheetah-run from the 17-d state, linear policy, OpenES (the sanity bar: >= 400 in 15 min)",
        "cheetah-run",
        "linear",
        es=STATE_ES,
        run=RunConfig(iterations=200, eval_episodes=8, checkpoint_every=10),
    ),
    Preset(
        "cheetah-run-state-mlp",
        "cheetah-run from the 17-d state, MLP (32, 32) policy, OpenES",
        "cheetah-run",
        "mlp",
        policy_options=(("hidden_sizes", (32, 32)),),
        es=dataclasses.replace(STATE_ES, population_size=256, sigma=0.02, learning_rate=0.01),
        run=RunConfig(iterations=400, eval_episodes=8, checkpoint_every=10),
    ),
    Preset(
        "cheetah-run-state-cmaes",
        "cheetah-run from the state, linear policy, CMA-ES through the evosax adapter",
        "cheetah-run",
        "linear",
        es=ESConfig(strategy="CMA_ES", population_size=64, sigma=0.1, antithetic=False),
        run=RunConfig(iterations=400, eval_episodes=8, checkpoint_every=10),
    ),
    *(
        Preset(
            f"{task}-pixels",
            f"{task} from 100x100 RGB: IAP hybrid (10, 5), 4x4 patches, top 10 -> LSTM(16), "
            f"action repeat {ACTION_REPEAT[task]}",
            task,
            "iap",
            pixels(task),
            iap(),
            PIXEL_ES,
            PIXEL_RUN,
        )
        for task in ACTION_REPEAT
    ),
    *(
        Preset(
            f"cheetah-run-pixels-{kernel}",
            f"cheetah-run-pixels with the {kernel} attention kernel (Figure 6 ablation)",
            "cheetah-run",
            "iap",
            pixels("cheetah-run"),
            iap(kernel),
            PIXEL_ES,
            PIXEL_RUN,
        )
        for kernel in FIG6_KERNELS
        if kernel != "hybrid-10-5"
    ),
    Preset(
        "cheetah-run-pixels-quick",
        "cheetah-run-pixels for a first run: population 30, Adam 0.08, 40 iterations (the README's first run)",
        "cheetah-run",
        "iap",
        pixels("cheetah-run"),
        iap(),
        dataclasses.replace(PIXEL_ES, population_size=30, learning_rate=0.08),
        RunConfig(iterations=40, eval_episodes=2, checkpoint_every=5),
    ),
)
