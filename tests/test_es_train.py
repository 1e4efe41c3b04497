"""``train`` end to end on the tiny point-mass env: learning, determinism, devices, metrics,
checkpoints, interruption and exact resume (also after SIGKILL)."""

from __future__ import annotations

import csv
import dataclasses
import json
import logging
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_es_envs import PointMass

from iap_mjx.configs import EnvSpec, ESConfig, PolicySpec, RunConfig, TrainConfig
from iap_mjx.es import train
from iap_mjx.es.results import evaluate_run, evaluate_run_episodes

TESTS = Path(__file__).resolve().parent


def small_config(**run) -> TrainConfig:
    return TrainConfig(
        env=EnvSpec("point-mass"),
        policy=PolicySpec("linear"),
        es=ESConfig(population_size=16, sigma=0.1, learning_rate=0.05, n_episodes=2),
        run=RunConfig(
            **{"iterations": 6, "eval_episodes": 4, "checkpoint_every": 3, "chunk_size": 8, "tensorboard": False, **run}
        ),
    )


def flat(tree) -> np.ndarray:
    return np.concatenate([np.ravel(np.asarray(x)) for x in jax.tree_util.tree_leaves(tree)])


def zero_policy_bar(env: PointMass) -> float:
    """The initial (zero) linear policy's mean return on 64 episodes plus 6 standard errors:
    a trained policy's evaluation must exceed it."""
    from iap_mjx.es.episode import run_episode
    from iap_mjx.policies import LinearPolicy

    keys = jax.random.split(jax.random.PRNGKey(99), 64)
    policy = LinearPolicy(6, 2)
    zero = np.array([float(run_episode(env, policy, policy.init(None), k, None, False).ret) for k in keys])
    return zero.mean() + 6 * zero.std() / np.sqrt(len(zero))


def test_training_beats_the_zero_action_policy():
    env = PointMass(episode_length=20)
    config = small_config(iterations=60, eval_episodes=64, checkpoint_every=0)
    config = dataclasses.replace(config, es=dataclasses.replace(config.es, population_size=32))
    result = train(config, env=env, progress=False)
    eval_return = result.history[-1]["eval_return"]
    assert eval_return > zero_policy_bar(env), eval_return


def test_same_seed_is_bit_identical_and_seed_matters():
    env = PointMass()
    a = train(small_config(checkpoint_every=0), env=env, progress=False)
    b = train(small_config(checkpoint_every=0), env=env, progress=False)
    c = train(small_config(checkpoint_every=0, seed=1), env=env, progress=False)
    np.testing.assert_array_equal(flat(a.params), flat(b.params))
    np.testing.assert_array_equal(flat(a.obs_stats), flat(b.obs_stats))
    assert not np.array_equal(flat(a.params), flat(c.params))


def test_one_and_two_devices_agree():
    assert len(jax.devices()) >= 2, "conftest should provide two CPU devices"
    env = PointMass()
    one = train(small_config(num_devices=1, checkpoint_every=0), env=env, progress=False)
    two = train(small_config(num_devices=2, checkpoint_every=0), env=env, progress=False)
    np.testing.assert_allclose(flat(one.params), flat(two.params), rtol=1e-4, atol=1e-5)
    returns = [[row["return_mean"] for row in r.history] for r in (one, two)]
    np.testing.assert_allclose(returns[0], returns[1], rtol=1e-4)


def test_fused_iterations_match_single_iterations():
    env = PointMass()
    single = train(small_config(checkpoint_every=0), env=env, progress=False)
    fused = train(small_config(checkpoint_every=0, iterations_per_call=3), env=env, progress=False)
    np.testing.assert_allclose(flat(single.params), flat(fused.params), rtol=1e-5, atol=1e-6)


def test_metrics_files_and_policy_fn(tmp_path):
    env = PointMass()
    config = dataclasses.replace(small_config(), run=dataclasses.replace(small_config().run, tensorboard=True))
    result = train(config, env=env, run_dir=tmp_path, progress=False)
    rows = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert [r["iteration"] for r in rows] == list(range(1, 7))
    assert all(np.isfinite(r["eval_return"]) for r in rows)
    with open(tmp_path / "metrics.csv") as f:
        table = list(csv.DictReader(f))
    assert len(table) == 6 and float(table[2]["eval_return"]) == rows[2]["eval_return"]
    for row in rows:
        assert row["env_steps_per_s"] > 0 and row["compile_s"] > 0
        assert row["return_min"] <= row["return_mean"] <= row["return_max"]
        assert row["nan_episodes"] == 0 and row["contact_saturated_episodes"] == 0
    assert rows[-1]["env_steps"] == 6 * 16 * 2 * env.episode_length
    assert any((tmp_path / "tensorboard").iterdir())
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == ["3", "6"]
    obs = jnp.ones(6)
    action, state = result.policy_fn(result.params, obs, result.initial_policy_state(jax.random.PRNGKey(0)))
    assert action.shape == (2,) and state == ()
    returns = evaluate_run(tmp_path, episodes=5, env=env)
    assert returns.shape == (5,) and np.all(np.isfinite(returns))
    # an even split over the two devices (no padding row) returns every episode too, not one
    # device's share (it returned 2 of 4 before the evaluation's output was replicated)
    four = evaluate_run(tmp_path, episodes=4, env=env)
    assert four.shape == (4,) and len(set(four.tolist())) == 4


def test_evaluate_run_repeats_the_trainings_own_evaluation(tmp_path):
    """A checkpoint after ``k`` iterations, evaluated with the run's seed on its
    ``run.eval_episodes``, sees the episodes the training's centre evaluation at the start of
    iteration ``k + 1`` saw: the same returns (the row's mean and std), up to float rounding
    between the two programs' batches. Another iteration's keys give other returns."""
    import shutil

    env = PointMass()
    config = small_config()
    train(config, env=env, run_dir=tmp_path, progress=False)
    rows = [json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    shutil.rmtree(tmp_path / "checkpoints" / "6")  # the latest is now the checkpoint after 3
    returns = evaluate_run(tmp_path, episodes=config.run.eval_episodes, seed=config.run.seed, env=env)
    assert returns.mean() == pytest.approx(rows[3]["eval_return"], rel=1e-5, abs=1e-5)
    assert returns.std() == pytest.approx(rows[3]["eval_return_std"], rel=1e-4, abs=1e-5)
    other = evaluate_run(tmp_path, episodes=config.run.eval_episodes, seed=config.run.seed + 1, env=env)
    assert abs(other.mean() - rows[3]["eval_return"]) > 1e-3


@dataclasses.dataclass(frozen=True)
class StartPointMass(PointMass):
    """``PointMass`` that reports each episode's start ``x`` (drawn from the episode's key
    alone, whatever the policy) as an episode metric."""

    episode_metrics = ("start_x",)

    def reset(self, key):
        state = super().reset(key)
        return state.replace(metrics={"start_x": state.data["pos"][0]})

    def step(self, state, action):
        return super().step(state, action).replace(metrics=state.metrics)


def test_evaluate_run_episodes_of_another_checkpoint(tmp_path):
    """``episodes_of=k`` draws the episodes of checkpoint ``k``'s evaluation, whichever checkpoint's
    parameters play them: the checkpoint after 6 iterations on the episodes of the one after 3
    starts every episode where the checkpoint after 3 does, and not where its own do."""
    import shutil

    env = StartPointMass()
    config = small_config()
    train(config, env=env, run_dir=tmp_path, progress=False)
    late = evaluate_run_episodes(tmp_path, episodes=5, env=env)
    late_on_early = evaluate_run_episodes(tmp_path, episodes=5, env=env, episodes_of=3)
    shutil.rmtree(tmp_path / "checkpoints" / "6")  # the latest is now the checkpoint after 3
    early = evaluate_run_episodes(tmp_path, episodes=5, env=env)
    np.testing.assert_array_equal(late_on_early["start_x"], early["start_x"])
    assert not np.any(late["start_x"] == early["start_x"])
    assert not np.allclose(late_on_early["return"], early["return"])  # other parameters, same starts
    with pytest.raises(ValueError, match="episodes_of must be an int >= 0"):
        evaluate_run_episodes(tmp_path, episodes=5, env=env, episodes_of=-1)


def test_nan_episodes_are_counted_and_do_not_poison_the_update():
    env = PointMass(nan_wall=2.0)  # large perturbations push some members past the wall
    config = small_config(checkpoint_every=0)
    config = dataclasses.replace(config, es=dataclasses.replace(config.es, sigma=0.5))
    result = train(config, env=env, progress=False)
    bad = [row["nan_episodes"] for row in result.history]
    assert sum(bad) > 0 and all(b < 32 for b in bad), bad
    assert all(np.isfinite(row["return_mean"]) for row in result.history)
    assert np.all(np.isfinite(flat(result.params)))


@dataclasses.dataclass(frozen=True)
class FlaggingPointMass(PointMass):
    """``PointMass`` whose episodes set the sticky ``metrics["contact_saturated"]`` flag:
    ``"always"``, or ``"right"`` when the start position has ``x > 0`` (about half)."""

    flag: str = "always"

    def _flagged(self, state):
        flagged = jnp.ones(()) if self.flag == "always" else (state.data["pos"][0] > 0).astype(jnp.float32)
        return state.replace(metrics={"contact_saturated": flagged})

    def reset(self, key):
        return self._flagged(super().reset(key))

    def step(self, state, action):
        return super().step(state, action).replace(metrics=state.metrics)


def test_contact_saturated_episodes_count_the_population_episodes_flagged():
    config = small_config(checkpoint_every=0, iterations=3)
    members = config.es.population_size * config.es.n_episodes  # 32; the 4 eval episodes not counted
    every = train(config, env=FlaggingPointMass(flag="always"), progress=False).history
    assert [row["contact_saturated_episodes"] for row in every] == [members] * 3
    some = [
        row["contact_saturated_episodes"]
        for row in train(config, env=FlaggingPointMass(flag="right"), progress=False).history
    ]
    assert all(0 < count < members for count in some), some


def test_shared_episodes_give_every_member_the_same_draws():
    """With ``es.shared_episodes`` each member's episode j starts where every other member's
    episode j does, so each start flagged (``x > 0``, about half) is flagged once per member:
    the count of flagged member episodes is a multiple of the population in every iteration
    (and, with two episodes a member, is the population itself where one of the two starts is
    flagged); without it the members' own draws give counts between."""
    config = small_config(checkpoint_every=0, iterations=4)
    population = config.es.population_size
    shared = dataclasses.replace(config, es=dataclasses.replace(config.es, shared_episodes=True))
    counts = [
        row["contact_saturated_episodes"]
        for row in train(shared, env=FlaggingPointMass(flag="right"), progress=False).history
    ]
    assert all(count % population == 0 for count in counts), counts
    assert population in counts, counts  # a member's two episodes are two draws, not one
    own = [
        row["contact_saturated_episodes"]
        for row in train(config, env=FlaggingPointMass(flag="right"), progress=False).history
    ]
    assert any(count % population for count in own), own


@pytest.mark.parametrize("at, saved", [(4, ["3"]), (5, ["3", "4"])])
def test_interrupt_saves_checkpoint_and_resume_is_exact(tmp_path, at, saved):
    """An interrupt while iteration ``at`` is being recorded keeps the last finished iteration:
    at 4 that is the periodic checkpoint 3 (saving it again would fail), at 5 it saves 4."""
    env = PointMass()
    whole = train(small_config(), env=env, progress=False)

    def interrupt(row):
        if row["iteration"] == at:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(small_config(), env=env, run_dir=tmp_path, progress=False, progress_fn=interrupt)
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == saved
    resumed = train(small_config(), env=env, run_dir=tmp_path, progress=False)
    np.testing.assert_array_equal(flat(whole.params), flat(resumed.params))
    assert [r["iteration"] for r in resumed.history] == list(range(1, 7))


def test_resume_with_a_different_config_is_refused(tmp_path):
    env = PointMass()
    train(small_config(iterations=3), env=env, run_dir=tmp_path, progress=False)
    other = dataclasses.replace(small_config(), es=dataclasses.replace(small_config().es, sigma=0.5))
    with pytest.raises(ValueError, match="es.sigma"):
        train(other, env=env, run_dir=tmp_path, progress=False)
    longer = train(small_config(iterations=6), env=env, run_dir=tmp_path, progress=False)
    assert longer.history[-1]["iteration"] == 6


def test_a_sigma_schedule_refuses_a_longer_resume(tmp_path):
    """The schedule decays over run.iterations: extending the run would make sigma jump."""

    def scheduled(iterations):
        config = small_config(iterations=iterations)
        return dataclasses.replace(config, es=dataclasses.replace(config.es, sigma_schedule="linear", sigma_final=0.01))

    train(scheduled(3), env=PointMass(), run_dir=tmp_path, progress=False)
    with pytest.raises(ValueError, match="run.iterations"):
        train(scheduled(6), env=PointMass(), run_dir=tmp_path, progress=False)


# The child kills itself with SIGKILL while recording iteration 8: checkpoint 6 is saved;
# iterations 7 and 8 are computed and their metrics rows handed to the writer, not checkpointed
# (the resume drops those rows and computes both again).
CHILD = textwrap.dedent("""
    import os, signal, sys
    sys.path.insert(0, {tests!r})
    from iap_mjx import runtime
    runtime.set_host_device_count(2)
    runtime.enable_compilation_cache({cache!r})
    from test_es_train import small_config
    from test_es_envs import PointMass
    from iap_mjx.es import train

    def kill_at_8(row):
        if row["iteration"] == 8:
            os.kill(os.getpid(), signal.SIGKILL)

    train(small_config(iterations=12), env=PointMass(), run_dir={run_dir!r}, progress=False,
          progress_fn=kill_at_8)
""")


def test_resume_after_sigkill_matches_uninterrupted_run(tmp_path):
    run_dir = tmp_path / "run"
    code = CHILD.format(tests=str(TESTS), cache=str(TESTS.parent / ".jax_cache"), run_dir=str(run_dir))
    child = subprocess.run([sys.executable, "-c", code], env=dict(os.environ))
    assert child.returncode == -signal.SIGKILL
    steps = sorted(int(p.name) for p in (run_dir / "checkpoints").iterdir() if p.name.isdigit())
    assert steps == [3, 6], steps
    env = PointMass()
    resumed = train(small_config(iterations=12), env=env, run_dir=run_dir, progress=False)
    whole = train(small_config(iterations=12), env=env, progress=False)
    np.testing.assert_array_equal(flat(whole.params), flat(resumed.params))
    np.testing.assert_array_equal(flat(whole.obs_stats), flat(resumed.obs_stats))
    assert [r["iteration"] for r in resumed.history] == list(range(1, 13))


def test_evosax_strategy_trains_through_the_adapter():
    """CMA-ES through the adapter (evosax minimises, we maximise) beats the zero policy as
    our OpenES does; with the fitness's sign lost it would walk away from the target."""
    env = PointMass(episode_length=20)
    config = small_config(iterations=60, eval_episodes=64, checkpoint_every=0)
    config = dataclasses.replace(
        # CMA-ES adapts its step size from sigma, the initial one: 0.5 reaches the target's
        # neighbourhood in 60 iterations
        config,
        es=dataclasses.replace(config.es, strategy="CMA_ES", antithetic=False, population_size=16, sigma=0.5),
    )
    result = train(config, env=env, progress=False)
    assert np.all(np.isfinite(flat(result.params)))
    assert result.history[-1]["eval_return"] > zero_policy_bar(env), result.history[-1]["eval_return"]


def test_a_chunk_size_that_would_deadlock_xla_is_refused_before_compiling(monkeypatch):
    """With jaxlib 0.10, vmapping more than ``env.max_chunk_size`` MJX envs per device on two
    devices deadlocks XLA:CPU (``iap_mjx.envs.dmc.serial_lapack_batch``): ``build`` refuses it,
    naming the setting and its valid values; one device, or a chunk within the limit, builds.
    Run as jaxlib 0.10.2 whichever jaxlib is installed (the limit's versions are tested with
    ``max_chunk_size``, in test_envs_quadruped)."""
    import jaxlib.version

    from iap_mjx import envs
    from iap_mjx.es.components import build

    monkeypatch.setattr(jaxlib.version, "__version_info__", (0, 10, 2))
    env = envs.make("cheetah-run")
    limit = env.max_chunk_size
    assert limit == (200_000 - 1) // (env.mj_model.nv**3 // 3) == 823
    config = TrainConfig(
        EnvSpec("cheetah-run"),
        PolicySpec("linear"),
        ESConfig(population_size=4),
        RunConfig(iterations=1, eval_episodes=0, chunk_size=limit + 1),
    )
    with pytest.raises(ValueError, match=rf"run.chunk_size = {limit + 1} .*valid values are 1..{limit}"):
        build(config, env=env)
    build(config, env=env, devices=jax.devices()[:1])
    build(dataclasses.replace(config, run=dataclasses.replace(config.run, chunk_size=limit)), env=env)


@dataclasses.dataclass(frozen=True)
class OwnPolicy:
    """A user's own policy, named nowhere in ``policies.FACTORIES``: ``tanh(W obs)``."""

    obs_size: int = 6
    action_size: int = 2

    def init(self, key):
        return {"w": jnp.zeros((self.obs_size, self.action_size))}

    def initial_state(self, key):
        return ()

    def apply(self, params, obs, state):
        return jnp.tanh(obs @ params["w"]), state


def test_a_users_own_policy_trains_without_a_name_and_is_logged_by_its_class(caplog):
    env = PointMass(episode_length=20)
    config = small_config(iterations=60, eval_episodes=64, checkpoint_every=0)
    config = dataclasses.replace(config, es=dataclasses.replace(config.es, population_size=32))
    with caplog.at_level(logging.INFO, logger="iap_mjx.es.train"):
        result = train(config, env=env, policy=OwnPolicy(), progress=False)
    assert "policy OwnPolicy: 12 parameters" in caplog.text  # the class trained, not the config's kind
    assert set(result.params) == {"w"} and result.params["w"].shape == (6, 2)
    assert result.history[-1]["eval_return"] > zero_policy_bar(env), result.history[-1]["eval_return"]


@dataclasses.dataclass(frozen=True)
class ScorelessPointMass(PointMass):
    """``PointMass`` whose reward is always 0: every member ties, as on a sparse task that no
    member reaches (finger-spin's first 100 iterations)."""

    def step(self, state, action):
        after = super().step(state, action)
        return after.replace(reward=jnp.zeros(()))


@pytest.mark.parametrize("env", [ScorelessPointMass(), PointMass()], ids=["tied", "scoring"])
def test_a_population_tied_throughout_is_reported_once(env, caplog):
    with caplog.at_level(logging.WARNING, logger="iap_mjx.es.bookkeeping"):
        result = train(small_config(checkpoint_every=0), env=env, progress=False)
    warnings = [r.getMessage() for r in caplog.records if "every member returned" in r.getMessage()]
    if isinstance(env, ScorelessPointMass):
        assert len(warnings) == 1, warnings  # once, though all 6 iterations tie
        assert warnings[0].startswith("iteration 1: every member returned 0, so the ES step is zero"), warnings
        # and it is: the zero-initialised linear policy's centre never moves
        assert not np.any(flat(result.params)), flat(result.params)
    else:
        assert warnings == [] and np.any(flat(result.params))
