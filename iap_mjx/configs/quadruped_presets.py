"""Presets on the A1-class quadruped: the PMTG low level learning to walk on the flat.

``quadruped-flat-pmtg``: ES trains the linear PMTG policy (``iap_mjx.policies.pmtg``) from the
state (IMU and joint angles; the TG phase is the policy's own) with a constant latent command,
on ``quadruped-flat``'s 10 s episodes, starting from the policy's default ``initial_tg`` (a trot
at 2.5 Hz that walks about 0.8 m/s with no residuals); the return is the capped distance walked in metres, so
the mean forward speed is ``return / 10 s``. ``RESULTS.md`` (section ``quadruped-walking``)
has its three seeds.
"""

from __future__ import annotations

from iap_mjx.configs.presets import Preset, register
from iap_mjx.configs.training import ESConfig, RunConfig

FLAT_PMTG = Preset(
    "quadruped-flat-pmtg",
    "quadruped-flat from the state: linear PMTG low level (trot TG + residuals), OpenES; "
    "return = metres walked in 10 s",
    "quadruped-flat", "pmtg",
    es=ESConfig(population_size=64, sigma=0.05, learning_rate=0.02, weight_decay=0.005),
    run=RunConfig(iterations=100, eval_episodes=8, checkpoint_every=10),
)

register(FLAT_PMTG)
