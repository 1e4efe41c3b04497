"""Presets on the A1-class quadruped: the PMTG low level learning to walk on the flat, and the
hierarchical policies on the walled course (the paper's Figure 11 and Table 2).

``quadruped-flat-pmtg``: ES trains the linear PMTG policy (``iap_mjx.policies.pmtg``) from the
state (IMU and joint angles; the TG phase is the policy's own) with a constant latent command,
on ``quadruped-flat``'s 10 s episodes, starting from the policy's default ``initial_tg`` (a
2.5 Hz trot that walks with no residuals); the return is the capped distance walked in metres,
so the mean forward speed is ``return / 10 s``. ``RESULTS.md`` (section ``quadruped-walking``)
has its three seeds.

``quadruped-turn-pmtg``: the same on ``quadruped-turn``, where each episode commands a yaw rate
(the observation's first entry) and the return is the distance walked along the commanded
heading: a low level that steers both ways on command, to start the hierarchy from.

``quadruped-walls-iap``, ``-cnn``, ``-blind``: the hierarchical policy
(``iap_mjx.policies.hierarchical``) on ``quadruped-walls`` from ``"pixels+state"`` (the 24x32
first-person camera for the high level, the 17-d state for the PMTG low level), 20 s episodes,
both levels trained together by ES from the low level's walking ``initial_tg`` (not from a
trained flat checkpoint: ``policy.low_level_init=PATH.npz`` does that). The high level: IAP with
deterministic ReLU features over 4x4 patches (top 10 centres -> a linear map; Table 2 varies
``policy.patch_size`` and ``policy.stride``), the paper's CNN (``ConvNet``), or the IAP one on a
zeroed image (blind, the control). A latent of 4, commands held 10 to 50 control steps. Same
ES and budget for the three, so that their curves compare: the flat preset's OpenES settings
(sigma 0.05, Adam 0.02, weight decay 0.005), which short runs on the course chose over two
others (RESULTS.md, ``fig11-tuning``), without observation normalisation (it needs vector
observations; the low level reads the raw state).

``quadruped-gates-iap``, ``-blind`` (beyond the paper: a procedural stand-in for its Figure 9's
Gibson navigation): the same hierarchy, ES and budget on ``quadruped-gates``, a corridor of
narrow gates and clutter (``iap_mjx.envs.quadruped_gates``), the high level seeing only the
first-person camera's depth (``"depth+state"``: 24x32x1 in ``[0, 1]``, 4 m of depth, the
state beside it for the low level). IAP's ReLU attention over 4x4 depth patches, or the same
high level on a zeroed image (blind, the control).
"""

from __future__ import annotations

import dataclasses

from iap_mjx.configs.presets import Options, Preset
from iap_mjx.configs.training import ESConfig, RunConfig

FLAT_PMTG = Preset(
    "quadruped-flat-pmtg",
    "quadruped-flat from the state: linear PMTG low level (trot TG + residuals), OpenES; "
    "return = metres walked in 10 s",
    "quadruped-flat",
    "pmtg",
    es=ESConfig(population_size=64, sigma=0.05, learning_rate=0.02, weight_decay=0.005),
    run=RunConfig(iterations=100, eval_episodes=8, checkpoint_every=10),
)

TURN_PMTG = Preset(
    "quadruped-turn-pmtg",
    "quadruped-turn from the state and a turn command: linear PMTG low level (trot TG + residuals), "
    "OpenES; return = metres walked along the commanded heading in 10 s",
    "quadruped-turn",
    "pmtg",
    es=FLAT_PMTG.es,
    run=dataclasses.replace(FLAT_PMTG.run, iterations=300),
)
"""The flat preset's policy and ES on ``quadruped-turn``, 300 iterations (at 100 the low level
turns both ways but walks a fraction of the flat trot's distance; RESULTS.md, section
``quadruped-turn``, has both): a low level that turns both ways on command, for the hierarchy's ``policy.low_level_init`` (its
command becomes the latent's first entry: ``iap_mjx.policies.hierarchical.commanded_low_level``)."""

COURSE_ENV: Options = (("obs_mode", "pixels+state"),)
"""The course seen through the first-person camera (24x32 RGB, its default size), the state
beside it for the low level."""
HIERARCHY: Options = (("latent_size", 4), ("duration_range", (10, 50)))
IAP_HIGH: Options = (
    ("high_level", "iap"),
    ("kernel", "relu"),
    ("patch_size", 4),
    ("top_l", 10),
    ("d_qk", 4),
    ("controller", "linear"),
)
CNN_HIGH: Options = (("high_level", "cnn"),)
COURSE_ES = dataclasses.replace(FLAT_PMTG.es, normalize_observations=False)
COURSE_RUN = RunConfig(iterations=200, eval_episodes=8, checkpoint_every=10)


def hierarchies(
    course: str, env_options: Options, seen: str, highs: tuple[tuple[str, Options, str], ...]
) -> tuple[Preset, ...]:
    """``<course>-<name>`` for each ``(name, high level options, what)`` of ``highs``: the
    hierarchy on ``course`` (``seen``: how the camera is read), the course's ES and budget."""
    hierarchy = dict(HIERARCHY)
    lo, hi = hierarchy["duration_range"]
    return tuple(
        Preset(
            f"{course}-{name}",
            f"{course}{seen}, hierarchical: {what} -> latent ({hierarchy['latent_size']}) held "
            f"{lo}-{hi} steps -> linear PMTG low level; return = metres along the course in 20 s",
            course,
            "hierarchical",
            env_options,
            high + HIERARCHY,
            COURSE_ES,
            COURSE_RUN,
        )
        for name, high, what in highs
    )


WALLS = hierarchies(
    "quadruped-walls",
    COURSE_ENV,
    "",
    (
        ("iap", IAP_HIGH, "IAP high level (ReLU features, 4x4 patches, top 10 -> linear)"),
        ("cnn", CNN_HIGH, "CNN high level (3 conv 3x3, 2x2 max pool, dense tanh 16)"),
        ("blind", IAP_HIGH + (("blind", True),), "blind high level (the IAP one on a zeroed image: the control)"),
    ),
)

GATES_ENV: Options = (("obs_mode", "depth+state"),)
"""The corridor through the first-person camera's depth channel (24x32, scaled to [0, 1] over
4 m), the state beside it for the low level."""

GATES = hierarchies(
    "quadruped-gates",
    GATES_ENV,
    " from depth",
    (
        ("iap", IAP_HIGH, "IAP high level over depth patches (ReLU features, 4x4 patches, top 10 -> linear)"),
        ("blind", IAP_HIGH + (("blind", True),), "blind high level (the IAP one on a zeroed depth image: the control)"),
    ),
)

PRESETS: tuple[Preset, ...] = (FLAT_PMTG, TURN_PMTG, *WALLS, *GATES)
