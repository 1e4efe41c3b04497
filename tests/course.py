"""What the quadruped courses' tests share: the presets' one-iteration budget, the course
statistics' metric columns, and native MuJoCo stepped the way the course env steps."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import mujoco
import numpy as np
import spread

SHRINK = [
    "env.episode_length=5",
    "es.population_size=4",
    "run.iterations=1",
    "run.eval_episodes=2",
    "run.checkpoint_every=0",
    "run.tensorboard=false",
]
"""A preset shrunk only in its budget: 5-step episodes, 4 members, one iteration."""


def course_columns(statistics: Sequence[str]) -> list[str]:
    """The metric columns of a course's per-episode ``statistics``: the population's mean
    (``<name>_mean``) and the centre's evaluation (``eval_<name>``) of each."""
    return [f"{prefix}{name}{suffix}" for name in statistics for prefix, suffix in (("", "_mean"), ("eval_", ""))]


def native_qpos(
    env,
    model: mujoco.MjModel,
    start,
    targets: np.ndarray,
    *,
    follow: Callable[[mujoco.MjData], None] | None = None,
    rng: np.random.Generator | None = None,
    sub_steps: int | None = None,
    touch_geom: int | None = None,
) -> tuple[np.ndarray, int]:
    """Native MuJoCo (float64) on ``model`` from the MJX data ``start`` under PD ``targets``
    ``(T, 12)``: ``qpos`` after each control step ``(T, nq)`` and how many physics steps had
    ``touch_geom`` in a contact. ``follow(data)``: moves the course's colliding obstacle
    copies after each control step, as the env does; ``rng`` nudges the state by one float32
    ulp after every physics step; ``sub_steps`` replaces the physics steps per control step."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = np.asarray(start.qpos), np.asarray(start.qvel)
    data.mocap_pos[:] = np.asarray(start.mocap_pos)
    qpos, touched = [], 0
    for target in targets:
        data.ctrl[:] = target
        for _ in range(env.n_sub_steps if sub_steps is None else sub_steps):
            mujoco.mj_step(model, data)
            if rng is not None:
                spread.nudge_state(data, rng)
            if touch_geom is not None:
                touched += sum(touch_geom in (c.geom1, c.geom2) and c.dist < 0 for c in data.contact[: data.ncon])
        if follow is not None:
            follow(data)
        qpos.append(data.qpos.copy())
    return np.array(qpos), touched


def check_against_native(env, model, start, targets, ours, *, follow, what: str, touch_geom: int | None = None):
    """``ours`` ``(T, nq)`` within 1e-3 plus native MuJoCo's own spread under float32 noise
    (``tests/spread.py``) of :func:`native_qpos`'s run from ``start``, and a native run with 4
    physics steps per control step instead of 5 outside it. Returns native's run and its touch
    count."""
    run = lambda **kw: native_qpos(env, model, start, targets, follow=follow, **kw)  # noqa: E731
    theirs, touched = run(touch_geom=touch_geom)
    qpos_spread = spread.spread(theirs, [run(rng=noise)[0] for noise in spread.noise_generators()])
    spread.assert_within_spread(np.array(ours), theirs, qpos_spread, atol=1e-3, what=what)
    wrong, _ = run(sub_steps=spread.wrong_sub_steps(env.n_sub_steps))
    spread.assert_wrong_step_is_caught(wrong, theirs, qpos_spread, atol=1e-3)
    return theirs, touched
