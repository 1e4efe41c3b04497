"""Presets on the Distracting Control Suite: ``dcs-<task>`` rows for the suite's tasks.

The IAP paper's Table 1 setting: the reference's native 240x320 RGB frames, static
distractions at medium difficulty (backgrounds, camera and colours), 2x2 patches
(``L = 19,200``), the top 10 patch centres into an LSTM controller (16 units), hybrid
features ``(m, r) = (10, 5)``; the action repeat of PlaNet/DrQ-style benchmarks per task.
OpenES with a population of 64, Adam at learning rate 0.1 and sigma 0.1 (:data:`DCS_ES`):
one setting for every task and seed, chosen on short runs of cartpole-swingup and
cheetah-run (``RESULTS.md``, section ``dcs-tuning``, has every run that informed it).
``dcs-<task>-cnn`` swaps the attention for a small convolutional network (:data:`CONVNET`)
and keeps everything else. ``dcs-<task>-quick`` (and ``dcs-<task>-cnn-quick``) is the same
policy on 10-step episodes, a population of 8 and small background frames: a smoke run for
tests.
"""

from __future__ import annotations

import dataclasses

from iap_mjx.configs.distraction import TASKS
from iap_mjx.configs.presets import ACTION_REPEAT, PIXEL_ES, PIXEL_RUN, Options, Preset, iap, pixels
from iap_mjx.configs.training import RunConfig

IAP_NATIVE: Options = iap(patch_size=2)
"""The IAP policy at the suite's native frames: 2x2 patches, top 10, hybrid (10, 5), LSTM(16)."""
CONVNET: Options = (
    ("channels", (8, 16, 16)),
    ("strides", (4, 4, 2)),
    ("embedding_size", 16),
    ("controller", "lstm"),
    ("hidden_sizes", (16,)),
)
"""The convolutional baseline (``ConvNetPolicy``): the same controller as IAP's, fed by three
3x3 convolutions (strides 4, 4, 2), a 2x2 max pool and a 16-unit embedding."""


DCS_ES = dataclasses.replace(PIXEL_ES, learning_rate=0.1, sigma=0.1)


# the presets' descriptions read the settings, so that they cannot drift apart
_ES_TEXT = (
    f"OpenES {DCS_ES.population_size}, {DCS_ES.optimizer.capitalize()} {DCS_ES.learning_rate:g}, sigma {DCS_ES.sigma:g}"
)
_CNN = dict(CONVNET)
_CNN_TEXT = (
    f"{len(_CNN['channels'])} conv 3x3, strides {', '.join(map(str, _CNN['strides']))}, 2x2 max pool, "
    f"dense {_CNN['embedding_size']} -> {_CNN['controller'].upper()}({', '.join(map(str, _CNN['hidden_sizes']))})"
)


def native(task: str, *, quick: bool = False) -> Options:
    """Env options: 240x320 RGB, static medium distractions, ``ACTION_REPEAT[task]``."""
    options = pixels(task, 240, 320) + (("distraction", "medium"), ("dynamic", False))
    if quick:
        options += (("episode_length", 10), ("background_size", 64), ("background_frames", 4))
    return options


QUICK_ES = dataclasses.replace(DCS_ES, population_size=8)
QUICK_RUN = RunConfig(iterations=2, eval_episodes=2, checkpoint_every=0, chunk_size=8)


def quick(preset: Preset) -> Preset:
    """``preset`` on 10-step episodes with small background frames, a population of 8 and 2
    iterations: a smoke run for tests."""
    return dataclasses.replace(
        preset,
        name=f"{preset.name}-quick",
        description=f"{preset.name} on 10-step episodes, population 8, 2 iterations (smoke)",
        env_options=native(preset.env, quick=True),
        es=QUICK_ES,
        run=QUICK_RUN,
    )


def _rows(task: str) -> tuple[Preset, Preset]:
    """``dcs-<task>`` (IAP) and ``dcs-<task>-cnn``."""
    return (
        Preset(
            f"dcs-{task}",
            f"{task} on the Distracting Control Suite (static, medium) at 240x320: IAP hybrid "
            f"(10, 5), 2x2 patches, top 10 -> LSTM(16), action repeat {ACTION_REPEAT[task]}; {_ES_TEXT}",
            task,
            "iap",
            native(task),
            IAP_NATIVE,
            DCS_ES,
            PIXEL_RUN,
        ),
        Preset(
            f"dcs-{task}-cnn",
            f"dcs-{task} with the convolutional baseline in place of attention ({_CNN_TEXT}); the same frames and ES",
            task,
            "convnet",
            native(task),
            CONVNET,
            DCS_ES,
            PIXEL_RUN,
        ),
    )


PRESETS: tuple[Preset, ...] = tuple(row for task in TASKS for full in _rows(task) for row in (full, quick(full)))
