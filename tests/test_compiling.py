"""``compiling.lower_afresh``: a program lowered after other work in the process is the module a
fresh lowering makes, so the persistent compilation cache (keyed on the module) finds it.

The program is the walls course's training call (hierarchical policy, MJX quadruped, walls),
whose lowering, without the caches cleared, depends on what the process traced before (the
jitted helpers a first trace emits once per call site are shared by a later one)."""

from __future__ import annotations

import re

import jax
import pytest

from iap_mjx import configs
from iap_mjx.compiling import lower_afresh
from iap_mjx.es.components import build, init_state
from iap_mjx.es.iteration import make_train_call


def _text(lowered) -> str:
    """The module's text without source locations (they are not in the cache's key)."""
    return re.sub(r"\s*loc\((?:[^()]|\([^()]*\))*\)", "", lowered.as_text(debug_info=False))


def _training_call(config):
    """The config's training call, built from scratch as each run of a report builds it, and
    the state it is lowered for."""
    parts = build(config)
    return jax.jit(make_train_call(parts, 1), out_shardings=parts.replicated), init_state(parts)


@pytest.mark.slow
def test_a_program_lowered_after_other_work_is_the_fresh_module():
    config = configs.apply_overrides(configs.get("quadruped-walls-blind"), ("es.population_size=4",))
    first = _text(lower_afresh(*_training_call(config)))
    call, state = _training_call(config)
    call.lower(state)  # other work: another run's program traced on the caches the first filled
    again = _text(lower_afresh(*_training_call(config)))
    assert again == first
