"""finger-spin against dm_control beyond the shared parity test: the collision-free initial
state distribution (against dm_control's own rejection sampler), the touch sensors and the
spin reward while the finger flicks the spinner, and dm_control's model edits."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import spread
from dm_control import suite
from scipy import stats
from test_envs_parity import Case, _flat, _our_rollouts, _states_before

from iap_mjx import envs
from iap_mjx.envs.dmc import physics_step

N_RESETS = 2048
RESET_BATCH = 64  # the shape tests/test_envs_parity.py resets with: one compiled program for both
P_VALUE = 1e-3  # per statistic; the seeds are fixed, so a pass is reproducible


@pytest.fixture(scope="module")
def finger():
    return envs.make("finger-spin")


def _dm_control_initial_qpos(n: int, seed: int) -> np.ndarray:
    env = suite.load("finger", "spin", task_kwargs={"random": seed})
    qpos = []
    for _ in range(n):
        env.reset()
        qpos.append(env.physics.data.qpos.copy())
    return np.array(qpos)


def test_initial_states_are_dm_controls_collision_free_distribution(finger):
    """2048 of our resets vs 2048 of dm_control's (its ``_set_random_joint_angles``: uniform
    joint angles redrawn until nothing touches; ~10% of draws touch).

    - Every one of ours is collision-free by native MuJoCo's own collision detection.
    - Joint distribution: a two-sample chi-square test of homogeneity on a 4x4x4 histogram
      of (proximal, distal, hinge) angles, and a two-sample Kolmogorov-Smirnov test per angle,
      each at p = 1e-3 (thresholds from the statistics' null distributions).
    """
    theirs = _dm_control_initial_qpos(N_RESETS, seed=0)
    reset = jax.jit(jax.vmap(finger.reset))
    keys = jax.random.split(jax.random.key(0), N_RESETS).reshape(-1, RESET_BATCH)
    states = [reset(batch) for batch in keys]
    ours = np.concatenate([np.asarray(state.data.qpos, np.float64) for state in states])
    assert all(np.all(np.asarray(state.data.qvel) == 0) for state in states)

    model = finger.mj_model
    data = mujoco.MjData(model)
    touching = 0
    for qpos in ours:
        data.qpos[:] = qpos
        mujoco.mj_forward(model, data)
        touching += data.ncon > 0
    assert touching == 0, f"{touching} of our initial states are in contact"

    low = np.array([model.jnt_range[0, 0], model.jnt_range[1, 0], -np.pi])
    high = np.array([model.jnt_range[0, 1], model.jnt_range[1, 1], np.pi])
    assert np.all((ours >= low) & (ours <= high))
    edges = [np.linspace(lo, hi, 5) for lo, hi in zip(low, high)]
    counts_ours = np.histogramdd(ours, edges)[0].ravel()
    counts_theirs = np.histogramdd(theirs, edges)[0].ravel()
    used = (counts_ours + counts_theirs) > 0
    # Equal sample sizes: sum (a - b)^2 / (a + b) is chi-square with (bins - 1) dof.
    chi2 = np.sum((counts_ours[used] - counts_theirs[used]) ** 2 / (counts_ours[used] + counts_theirs[used]))
    assert chi2 < stats.chi2.ppf(1 - P_VALUE, used.sum() - 1), (chi2, used.sum())
    critical_ks = np.sqrt(-np.log(P_VALUE / 2) / 2) * np.sqrt(2 / N_RESETS)
    for joint in range(3):
        ks = stats.ks_2samp(ours[:, joint], theirs[:, joint]).statistic
        assert ks < critical_ks, (joint, ks, critical_ks)


def _square_wave_rollout(seed: int, steps: int = 200) -> dict:
    """dm_control's finger-spin under square-wave actions that make it flick the spinner,
    stepped as ``env.step`` does (control, then 2 physics steps), in the format of
    ``test_envs_parity``'s references, plus the state at the start of each control step's
    last physics step (where the touch sensors are computed)."""
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi, 2)
    actions = np.sign(np.sin(np.arange(steps)[:, None] / 20.0 * 2 * np.pi + phase))
    env = suite.load("finger", "spin", task_kwargs={"random": 0})
    timestep = env.reset()
    physics = env.physics
    start = {
        "qpos": physics.data.qpos.copy(),
        "qvel": physics.data.qvel.copy(),
        "obs": _flat(timestep.observation),
        "info": {},
    }
    record = {key: [] for key in ("last_qpos", "last_qvel", "qpos", "qvel", "obs", "reward")}
    for action in actions:
        physics.set_control(action)
        for sub_step in range(env._n_sub_steps):
            if sub_step == env._n_sub_steps - 1:
                record["last_qpos"].append(physics.data.qpos.copy())
                record["last_qvel"].append(physics.data.qvel.copy())
            physics.step()
        record["qpos"].append(physics.data.qpos.copy())
        record["qvel"].append(physics.data.qvel.copy())
        record["obs"].append(_flat(env.task.get_observation(physics)))
        record["reward"].append(env.task.get_reward(physics))
    return dict(start=start, actions=actions, **{key: np.array(value) for key, value in record.items()})


@pytest.mark.slow
def test_touch_and_spin_reward_match_dm_control(finger):
    """Seed 5's square waves touch the spinner on 16 control steps and spin it past
    15 rad/s on 8.

    - Touch at identical states: from dm_control's state at the start of each control step's
      last physics step, our physics step's touch sensors (``log1p`` of the normal force)
      within 1e-2 of dm_control's (measured 4e-3: 8 float32 Newton iterations vs 200 in
      float64).
    - Observation and reward at identical states (``test_envs_parity``'s machinery, so the
      compiled programs are shared): position and velocity to float32 precision, the reward
      exactly, on all 200 steps.
    - Trajectory: the first 100 control steps (9 of them touching) within 1e-2 of dm_control's
      observations plus 100x dm_control's own spread under float32 noise
      (``tests/spread.py``), rewards equal up to that spread. Measured here: the spread is
      needed from step ~65 on (a factor of 7.4 by step 100), and a physics step per control
      step too few (tested) needs 3.6e6. Later touches add up what rounding does not explain:
      8 float32 Newton iterations against dm_control's 200 leave each touch's contact force
      ~4e-3 apart (above), ~1e4 float32 ulps, and by step 123 the trajectory needs 150x
      the spread, by step 150 860x.
    - One step: from each of the 200 states, one control step of ours against dm_control's
      (``test_envs_parity``'s), within 1e-2 plus 100x dm_control's spread over that step; the
      touching steps past the trajectory's window are checked here.
    """
    reference = _square_wave_rollout(seed=5)
    touch = reference["obs"][:, 7:]
    assert np.sum(np.any(touch > 0, axis=1)) >= 10 and np.sum(reference["reward"]) >= 5
    ours = _our_rollouts(Case("finger-spin", 1e-2, 0.0), reference)

    @jax.jit
    @jax.vmap
    def touch_after(last_qpos, last_qvel, action):
        data = finger.reset_to(last_qpos, last_qvel).data.replace(ctrl=action)
        return finger.state_observation(physics_step(finger.mjx_model, data))[7:]

    actions = jnp.asarray(reference["actions"], jnp.float32)
    our_touch = touch_after(reference["last_qpos"], reference["last_qvel"], actions)
    np.testing.assert_allclose(np.asarray(our_touch), touch, atol=1e-2)

    np.testing.assert_allclose(ours["same_obs"][:, :7], reference["obs"][:, :7], rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(ours["same_reward"], reference["reward"])

    window = slice(0, 100)
    assert np.sum(np.any(touch[window] > 0, axis=1)) >= 8
    np.testing.assert_allclose(ours["first_obs"], reference["start"]["obs"], rtol=1e-5, atol=1e-5)
    actions = reference["actions"][window]
    obs, reward = reference["obs"][window], reference["reward"][window]
    obs_spread, reward_spread = spread.dm_control_spread("finger-spin", 0, actions, obs, reward)
    spread.assert_within_spread(ours["obs"][window], obs, obs_spread, atol=1e-2, what="finger-spin observations")
    spread.assert_within_spread(ours["reward"][window], reward, reward_spread, atol=0.0, what="finger-spin rewards")
    wrong, _ = spread.dm_control_run("finger-spin", 0, actions, sub_steps=spread.wrong_sub_steps(finger.n_sub_steps))
    spread.assert_wrong_step_is_caught(wrong, obs, obs_spread, atol=1e-2)

    # One step from each of the 200 states, the touches past the window included.
    spread.assert_one_steps_within_spread(
        "finger-spin",
        0,
        _states_before(reference),
        reference["actions"],
        (reference["obs"], reference["reward"]),
        (ours["step_obs"], ours["step_reward"]),
        obs_atol=1e-2,
        reward_atol=0.0,
    )


def test_the_geoms_left_without_collisions_never_touch():
    """``FingerSpin`` drops the collision flags of geoms that no pose brings into contact.

    On dm_control's own model (every pair MuJoCo would test), over 1000 random poses of all
    three joints on the full circle (beyond the joint limits), each pair with a dropped geom
    stays more than 2 cm apart by ``mj_geomDistance`` (the closest, fingertip to ground, is
    0.4 - 0.371 = 0.029 m); and in dm_control's simulation (9 episodes of 1000 steps:
    uniform, square-wave and bang-bang actions) every contact is one of the pairs we keep.
    """
    from mujoco.mjx._src import collision_driver

    from iap_mjx.envs.finger import _NEVER_TOUCHING

    env = suite.load("finger", "spin", task_kwargs={"random": 0})
    env.reset()
    model = env.physics.model.ptr
    data = mujoco.MjData(model)
    dropped = {mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name) for name in _NEVER_TOUCHING}
    pairs = [(a, b) for a, b, *_ in collision_driver.geom_pairs(model)]
    checked = [pair for pair in pairs if set(pair) & dropped]
    kept = {frozenset(pair) for pair in pairs if not set(pair) & dropped}
    assert len(checked) == 12 and len(kept) == 3
    rng = np.random.default_rng(0)
    closest = np.inf
    fromto = np.zeros(6)
    for qpos in rng.uniform(-np.pi, np.pi, (1000, 3)):
        data.qpos[:] = qpos
        mujoco.mj_kinematics(model, data)
        for a, b in checked:
            closest = min(closest, mujoco.mj_geomDistance(model, data, a, b, 1.0, fromto))
    assert closest > 0.02, closest  # the fingertip's closest approach to the ground: 0.029

    spec = env.action_spec()
    for episode in range(9):
        env.reset()
        phase = rng.uniform(0, 2 * np.pi, 2)
        for t in range(1000):
            if episode % 3 == 0:
                action = rng.uniform(spec.minimum, spec.maximum)
            elif episode % 3 == 1:
                action = np.sign(np.sin(t / 20.0 * 2 * np.pi + phase))
            else:
                action = np.where(rng.random(2) < 0.5, -1.0, 1.0)
            env.step(action)
            contacts = env.physics.data.contact[: env.physics.data.ncon]
            assert all(frozenset((c.geom1, c.geom2)) in kept for c in contacts)
