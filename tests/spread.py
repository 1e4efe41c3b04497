"""The reference's own spread: how far a float32 port may stray from native MuJoCo on any CPU.

XLA:CPU rounds the same float32 program differently on different instruction sets (AVX-512,
AVX2, NEON) and with different compiler flags, and a trajectory through contacts amplifies
such differences: a foot that grazes the floor at one step touches it in one rounding and not
in another. A fixed tolerance over a long trajectory therefore passes on the machine where it
was measured and fails on another. This module bounds the gap by what native MuJoCo itself
does under float32-size noise instead:

- ``RUNS`` native runs from the reference's start, each with every coordinate of ``qpos`` and
  ``qvel`` moved to a neighbouring float32 (one ulp, random sign) after every physics step:
  the rounding a float32 port adds at every step, added to the float64 reference.
- ``spread``: per step and entry, the largest gap of those runs from the noiseless reference,
  as a running maximum over steps (a gap that has opened does not close again).
- The check: ``|ours - reference| <= atol + FACTOR * spread``. Where the reference is stable
  (before the first impact) the spread is ~1e-7 and ``atol`` is the bound; where the
  reference's own runs part, so may ours.

Where the reference's own runs part for good (walker's falls, the quadruped's feet), the bound
grows past the range the entries take at all and a trajectory check says nothing more:
``informative_steps`` is how many leading steps the bound stays below a tenth of the range of
every entry that varies enough for that, and a wrong physics step must break the bound within them
(``assert_wrong_step_is_caught``). On the machine this was written on that is 19 of walker-walk's
200 steps, 73 of finger's touching 100, 84 of the walled course's 100 (the gates': 84 of 86, and
every step of their 40-step runs), and every step of the other tasks. For the dm_control tasks the physics step is also checked one control step at
a time from each of the reference's states (``dm_control_steps``), where nothing has had time
to part.

``FACTOR`` covers that our step's rounding is larger than one ulp (float32 throughout, and for
the dm_control tasks 8 Newton iterations against dm_control's 100): the largest factor any
test needed on the machine where this was written is 14 (walker-walk, 200 steps), and a wrong
physics step needs over 1e5 (every test checks that a native run with one physics step per
control step too few or too many breaks the bound, so the bound's power is measured on every
machine that runs it).
"""

from __future__ import annotations

import mujoco
import numpy as np
from dm_control import suite
from dm_control.rl import control

RUNS = 16
FACTOR = 100.0
INFORMATIVE = 0.1
"""A step's bound is informative while it is below this share of the range over the reference
trajectory of every entry that varies enough for that (:func:`informative_steps`)."""


def float32_nudge(x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``x`` with every entry moved to a neighbouring float32 (random direction), as float64."""
    toward = np.where(rng.random(x.shape) < 0.5, -np.inf, np.inf).astype(np.float32)
    return np.nextafter(x.astype(np.float32), toward).astype(np.float64)


def nudge_state(data: mujoco.MjData, rng: np.random.Generator) -> None:
    """Moves ``qpos`` and ``qvel`` of ``data`` by one float32 ulp each, in place."""
    data.qpos[:] = float32_nudge(data.qpos, rng)
    data.qvel[:] = float32_nudge(data.qvel, rng)


def noise_generators(seed: int = 100, runs: int = RUNS) -> list[np.random.Generator]:
    """The fixed noise streams of the ``runs`` perturbed reference runs."""
    return [np.random.default_rng(seed + k) for k in range(runs)]


def spread(reference: np.ndarray, runs: list[np.ndarray] | np.ndarray) -> np.ndarray:
    """``(T, ...)``: running maximum over steps of ``max_k |runs[k] - reference|``."""
    gaps = np.max(np.abs(np.asarray(runs) - np.asarray(reference)[None]), axis=0)
    return np.maximum.accumulate(gaps, axis=0)


def violations(
    ours: np.ndarray, reference: np.ndarray, spread_: np.ndarray, *, atol: float, factor: float = FACTOR
) -> np.ndarray:
    """Boolean ``(T, ...)``: where ``|ours - reference|`` exceeds ``atol + factor * spread``."""
    return np.abs(np.asarray(ours) - reference) > atol + factor * spread_


def assert_within_spread(
    ours: np.ndarray,
    reference: np.ndarray,
    spread_: np.ndarray,
    *,
    atol: float,
    factor: float = FACTOR,
    what: str = "trajectory",
) -> None:
    """Fails at the first step where ``ours`` leaves ``reference`` by more than
    ``atol + factor * spread``, naming the step, the entry, the gap and the bound."""
    bad = violations(ours, reference, spread_, atol=atol, factor=factor)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        gap = abs(float(np.asarray(ours)[where]) - float(reference[where]))
        raise AssertionError(
            f"{what}: {int(bad.sum())} of {bad.size} entries out of bounds; first at (step, "
            f"entry) {where}: |ours - reference| = {gap:.3g} > atol {atol:g} + {factor:g} x the "
            f"reference's own spread {float(spread_[where]):.3g}"
        )


def informative_steps(reference: np.ndarray, spread_: np.ndarray, *, atol: float, factor: float = FACTOR) -> int:
    """How many leading steps the bound ``atol + factor * spread`` stays below
    :data:`INFORMATIVE` times the range over all steps of every entry whose range allows that
    (above ``atol / INFORMATIVE``; a narrower entry is checked against a bound of about its
    own range, which tells nothing of the steps). Every step when no entry varies that much."""
    steps = len(reference)
    reference, bound = np.reshape(reference, (steps, -1)), atol + factor * np.reshape(spread_, (steps, -1))
    scale = np.ptp(reference, axis=0)
    varying = scale > atol / INFORMATIVE
    tight = np.all(bound[:, varying] < INFORMATIVE * scale[varying], axis=1)
    return steps if tight.all() else int(np.argmin(tight))


def assert_wrong_step_is_caught(
    wrong: np.ndarray, reference: np.ndarray, spread_: np.ndarray, *, atol: float, factor: float = FACTOR
) -> None:
    """The bound's power: a trajectory of a wrong physics step must break it within the steps
    where the bound is informative (:func:`informative_steps`)."""
    steps = informative_steps(reference, spread_, atol=atol, factor=factor)
    assert steps > 0, "the bound is informative at no step: the spread is wider than a tenth of an entry's range"
    assert violations(wrong, reference, spread_, atol=atol, factor=factor)[:steps].any(), (
        f"a native run with a wrong number of physics steps stays within the bound over the {steps} "
        "steps where it is informative: the bound cannot tell a wrong step from rounding"
    )


def wrong_sub_steps(n_sub_steps: int) -> int:
    """A wrong number of physics steps per control step: one fewer (one more if that is 0)."""
    return n_sub_steps - 1 if n_sub_steps > 1 else 2


def dm_control_run(
    name: str, seed: int, actions: np.ndarray, *, rng: np.random.Generator | None = None, sub_steps: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """dm_control's ``name`` (reset with ``seed``) under ``actions``: flat observations
    ``(T, n)`` and rewards ``(T,)`` after each control step.

    Stepped as dm_control's legacy ``physics.step`` steps: for Euler models ``mj_step2`` then
    ``mj_step1`` per physics step (so acceleration-stage sensors such as finger's touch sensors
    come from the last physics step's start); for RK4 models (cartpole), whose steps
    ``mj_step2`` would integrate with Euler, a whole ``mj_step`` per physics step and one
    ``mj_step1`` after the last. One physics step at a time so that ``rng`` can nudge the state
    after each integration (``None``: no noise, and the run equals ``env.step``'s bit for bit);
    ``sub_steps`` replaces the task's physics steps per control step (a wrong step, for the
    bound's power).
    """
    env = _loaded(name, seed)
    steps = [_control_step(env, action, rng, sub_steps) for action in actions]
    return np.array([obs for obs, _ in steps]), np.array([reward for _, reward in steps])


def dm_control_steps(
    name: str,
    seed: int,
    qpos: np.ndarray,
    qvel: np.ndarray,
    actions: np.ndarray,
    *,
    rng: np.random.Generator | None = None,
    sub_steps: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One control step of dm_control's ``name`` (reset with ``seed``, for its task's
    variables) from each state ``qpos[t], qvel[t]`` under ``actions[t]``: observations
    ``(T, n)`` and rewards ``(T,)`` after it; ``rng`` and ``sub_steps`` as in
    :func:`dm_control_run`."""
    env = _loaded(name, seed)
    steps = []
    for position, velocity, action in zip(qpos, qvel, actions):
        with env.physics.reset_context():
            env.physics.data.qpos[:], env.physics.data.qvel[:] = position, velocity
        steps.append(_control_step(env, action, rng, sub_steps))
    return np.array([obs for obs, _ in steps]), np.array([reward for _, reward in steps])


def dm_control_step_spread(
    name: str,
    seed: int,
    qpos: np.ndarray,
    qvel: np.ndarray,
    actions: np.ndarray,
    reference_obs: np.ndarray,
    reference_reward: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Per state, the largest gap of :func:`dm_control_steps` under float32 noise from its
    noiseless run (``reference_obs`` ``(T, n)``, ``reference_reward`` ``(T,)``): each step
    starts afresh, so no running maximum."""
    runs = [dm_control_steps(name, seed, qpos, qvel, actions, rng=rng) for rng in noise_generators()]
    return tuple(
        np.max(np.abs(np.array([run[i] for run in runs]) - reference[None]), axis=0)
        for i, reference in enumerate((reference_obs, reference_reward))
    )


def assert_one_steps_within_spread(
    name: str,
    seed: int,
    states: tuple[np.ndarray, np.ndarray],
    actions: np.ndarray,
    reference: tuple[np.ndarray, np.ndarray],
    ours: tuple[np.ndarray, np.ndarray],
    *,
    obs_atol: float,
    reward_atol: float,
) -> None:
    """One control step of ours from each of dm_control's states against dm_control's.

    ``states``: ``(qpos (T, nq), qvel (T, nv))`` before each step; ``reference``: the
    trajectory's observations ``(T, n)`` and rewards ``(T,)`` after each; ``ours``: our
    observations and rewards after one step from each state. dm_control's own step from a state
    set afresh must be the trajectory's (float64; the solver's warm start is all that differs);
    ours must be within ``atol`` plus :data:`FACTOR` times dm_control's spread over that one
    step (:func:`dm_control_step_spread`); and a wrong number of physics steps must break that
    bound at more than half of the states (the bound's power)."""
    qpos, qvel = states
    reference_obs, reference_reward = reference
    fresh_obs, fresh_reward = dm_control_steps(name, seed, qpos, qvel, actions)
    np.testing.assert_allclose(fresh_obs, reference_obs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(fresh_reward, reference_reward, rtol=0, atol=1e-9)
    obs_spread, reward_spread = dm_control_step_spread(name, seed, qpos, qvel, actions, reference_obs, reference_reward)
    assert_within_spread(ours[0], reference_obs, obs_spread, atol=obs_atol, what=f"{name} one-step observations")
    assert_within_spread(ours[1], reference_reward, reward_spread, atol=reward_atol, what=f"{name} one-step rewards")
    n_sub_steps = _loaded(name, seed)._n_sub_steps
    wrong, _ = dm_control_steps(name, seed, qpos, qvel, actions, sub_steps=wrong_sub_steps(n_sub_steps))
    caught = violations(wrong, reference_obs, obs_spread, atol=obs_atol).any(axis=1)
    assert caught.mean() > 0.5, (
        f"a wrong physics step breaks the one-step bound at only {caught.mean():.0%} of the states"
    )


def _loaded(name: str, seed: int) -> control.Environment:
    """dm_control's ``name``, loaded with task seed ``seed`` and reset."""
    domain, task = name.split("-")
    env = suite.load(domain, task, task_kwargs={"random": seed})
    env.reset()
    return env


def _control_step(
    env: control.Environment, action: np.ndarray, rng: np.random.Generator | None, sub_steps: int | None
) -> tuple[np.ndarray, float]:
    """One control step of the loaded dm_control ``env`` as :func:`dm_control_run` steps it:
    the flat observation and the reward after it."""
    physics = env.physics
    model, data = physics.model.ptr, physics.data.ptr
    rk4 = model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
    env.task.before_step(action, physics)
    for _ in range(env._n_sub_steps if sub_steps is None else sub_steps):
        (mujoco.mj_step if rk4 else mujoco.mj_step2)(model, data)
        if rng is not None:
            nudge_state(data, rng)
        if not rk4:
            mujoco.mj_step1(model, data)
    if rk4:
        mujoco.mj_step1(model, data)
    env.task.after_step(physics)
    return flat(env.task.get_observation(physics)), env.task.get_reward(physics)


def dm_control_spread(
    name: str, seed: int, actions: np.ndarray, reference_obs: np.ndarray, reference_reward: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``spread`` of dm_control's observations and rewards under float32 noise."""
    runs = [dm_control_run(name, seed, actions, rng=rng) for rng in noise_generators()]
    return (spread(reference_obs, [obs for obs, _ in runs]), spread(reference_reward, [reward for _, reward in runs]))


def flat(observation) -> np.ndarray:
    """dm_control's observation dict as one flat vector, in the dict's order."""
    return np.concatenate([np.atleast_1d(v).ravel() for v in observation.values()])
