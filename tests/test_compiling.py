"""``compiling.lower_afresh``: a program lowered after other work in the process is the module a
fresh process lowers, so the persistent compilation cache (keyed on the module) finds the entry
that process wrote; and the training call and the centre's evaluation, lowered through it, load
what the same work compiled before.

The program is the walls course's training call (hierarchical policy, MJX quadruped, walls),
whose lowering, without the caches cleared, depends on what the process traced before (the
jitted helpers a first trace emits once per call site are shared by a later one)."""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys
from pathlib import Path

import jax
import pytest

from iap_mjx import configs
from iap_mjx.compiling import lower_afresh
from iap_mjx.es.components import build, init_state
from iap_mjx.es.iteration import make_train_call

# A fresh process, set up as conftest sets up this one (the XLA flags and the partitioner come
# through the environment), lowers the program with nothing traced before it: the reference.
FRESH = f"""
import sys
from iap_mjx import runtime
runtime.hoist_large_constants()
runtime.set_host_device_count(2)
runtime.disable_dm_control_rendering()
sys.path.insert(0, {str(Path(__file__).resolve().parent)!r})
import test_compiling as here
print(here.digest(here.training_call(here.CONFIG)[0].lower(here.training_call(here.CONFIG)[1])))
"""

CONFIG = ("quadruped-walls-blind", ("es.population_size=4",))


def digest(lowered) -> str:
    """SHA-256 of the module's text without source locations (they are not in the cache's key)."""
    text = re.sub(r"\s*loc\((?:[^()]|\([^()]*\))*\)", "", lowered.as_text(debug_info=False))
    return hashlib.sha256(text.encode()).hexdigest()


def training_call(preset_and_overrides):
    """The preset's training call, built from scratch as each run of a report builds it, and the
    state it is lowered for."""
    preset, overrides = preset_and_overrides
    parts = build(configs.apply_overrides(configs.get(preset), overrides))
    return jax.jit(make_train_call(parts, 1), out_shardings=parts.replicated), init_state(parts)


@pytest.mark.slow
def test_a_program_lowered_after_other_work_is_the_module_a_fresh_process_lowers():
    fresh = subprocess.run([sys.executable, "-c", FRESH], capture_output=True, text=True, check=True).stdout.strip()
    # other work: another run's program, then this one, traced on the caches they fill
    call, state = training_call(("quadruped-walls-iap", ("es.population_size=4",)))
    call.lower(state)
    call, state = training_call(CONFIG)
    warm = digest(call.lower(state))
    # the premise: lowered plainly after that work, the module is not the fresh one
    assert warm != fresh, "JAX now lowers the same module after other work: lower_afresh may be unneeded"
    assert digest(lower_afresh(*training_call(CONFIG))) == fresh


def _cache_events(work) -> tuple[int, int]:
    """The persistent cache's hits and misses (JAX's own events) while ``work()`` runs."""
    events = []

    def record(event, **kwargs):
        events.append(event)

    jax.monitoring.register_event_listener(record)
    try:
        work()
    finally:
        jax.monitoring.unregister_event_listener(record)
    return tuple(events.count(f"/jax/compilation_cache/cache_{what}") for what in ("hits", "misses"))


@pytest.mark.slow
def test_a_training_and_an_evaluation_after_other_work_load_the_programs_compiled_before(tmp_path):
    """The training call (``es.train``: a report's runs one after another in one process) and
    the centre's evaluation (``es.evaluate_run_episodes``: a report's evaluations) lower their
    programs afresh: after another program was traced, each finds what the same work compiled
    before in the persistent cache (JAX's own cache events: hits, no misses)."""
    from iap_mjx import es

    config = configs.apply_overrides(
        configs.get(CONFIG[0]),
        (*CONFIG[1], "run.iterations=1", "env.episode_length=10", "run.eval_episodes=1", "run.tensorboard=false"),
    )
    es.train(config, run_dir=tmp_path / "first", progress=False)  # compiled, or loaded: cached from here on
    es.evaluate_run_episodes(tmp_path / "first", episodes=2)

    def other_work():
        call, state = training_call(("quadruped-walls-iap", ("es.population_size=4",)))
        call.lower(state)

    other_work()
    hits, misses = _cache_events(lambda: es.train(config, run_dir=tmp_path / "second", progress=False))
    assert (hits > 0, misses) == (True, 0)
    other_work()
    hits, misses = _cache_events(lambda: es.evaluate_run_episodes(tmp_path / "first", episodes=2))
    assert (hits > 0, misses) == (True, 0)
