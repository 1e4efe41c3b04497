"""What the quadruped courses' tests share: the presets' one-iteration budget, the course
statistics' metric columns, native MuJoCo stepped the way the course env steps, and what a
run's episode video of a course shows, and native MuJoCo's contacts at our states."""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import spread
from mujoco import mjx

SHRINK = [
    "env.episode_length=5",
    "es.population_size=4",
    "run.iterations=1",
    "run.eval_episodes=2",
    "run.checkpoint_every=0",
    "run.tensorboard=false",
]
"""A preset shrunk only in its budget: 5-step episodes, 4 members, one iteration."""


def check_scene_video(path, camera_shape: tuple[int, int] = (24, 32)) -> None:
    """A course run's ``episode.mp4`` (5-step episodes) is the scene from the camera that
    follows the robot (``recording.SCENE_VIDEO_SIZE``) with the robot's own view inset in its
    top-right corner: there, right of the caption's text, the caption bar is black where the
    scene behind it is bright sky (H.264 blurs it a little)."""
    import imageio.v3 as iio

    from iap_mjx.viz import drawing, recording

    frames = iio.imread(path, plugin="pyav")
    assert 1 <= len(frames) <= 5 and frames.shape[1:] == (*recording.SCENE_VIDEO_SIZE, 3)
    scale = 4  # the video's inset scale; the 24x32 view fits the scene at it (drawing.fit_inset)
    top, left = drawing.INSET_MARGIN, recording.SCENE_VIDEO_SIZE[1] - drawing.INSET_MARGIN - camera_shape[1] * scale
    caption = frames[:, top + 3 : top + 13, left + 96 : left + camera_shape[1] * scale - 4].astype(float)
    sky = frames[:, top + 3 : top + 13, left - 60 : left - 20].astype(float)  # beside the inset
    assert caption.mean() < 40 and sky.mean() > 120, (caption.mean(), sky.mean())


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


SHALLOW = 1e-3
"""Metres: MJX's collision routines and native MuJoCo's may disagree whether a contact this
shallow exists (MJX's capsule-box routine misses some that native's finds)."""


def native_touches(model: mujoco.MjModel, states: Sequence, geom: int) -> list[float]:
    """Per state (an ``mjx.Data`` with its position stage current, e.g. after each env step):
    native MuJoCo's closest contact distance of ``geom`` (``inf``: no contact) given the state's
    ``qpos``, ``qvel`` and ``mocap_pos``."""
    data = mujoco.MjData(model)
    closest = []
    for state in states:
        data.qpos[:], data.qvel[:], data.mocap_pos[:] = (
            np.asarray(x) for x in (state.qpos, state.qvel, state.mocap_pos)
        )
        mujoco.mj_forward(model, data)
        closest.append(min((c.dist for c in data.contact[: data.ncon] if geom in (c.geom1, c.geom2)), default=np.inf))
    return closest


def mjx_touches(model: mujoco.MjModel) -> Callable[[Sequence, int], list[bool]]:
    """A compiled check on ``model``: given states and a geom, per state whether MJX's own
    collision, run at the state's ``qpos``, ``qvel`` and ``mocap_pos``, has ``geom`` in a
    contact at zero or negative distance. The geom is an argument, so one compile serves every
    geom and call of the same number of states."""
    mx = mjx.put_model(model)

    @jax.jit
    @functools.partial(jax.vmap, in_axes=(0, 0, 0, None))
    def touch(qpos, qvel, mocap_pos, geom):
        data = mjx.forward(mx, mjx.make_data(mx).replace(qpos=qpos, qvel=qvel, mocap_pos=mocap_pos))
        contact = data._impl.contact
        return jnp.any(((contact.geom1 == geom) | (contact.geom2 == geom)) & (contact.dist <= 0.0))

    def touches(states: Sequence, geom: int) -> list[bool]:
        stacked = [jnp.stack([getattr(s, name) for s in states]) for name in ("qpos", "qvel", "mocap_pos")]
        return [bool(x) for x in touch(*stacked, jnp.int32(geom))]

    return touches


def check_touches(
    ours: Sequence[bool],
    model: mujoco.MjModel,
    states: Sequence,
    geom: int,
    *,
    at_least: int,
    touches: Callable[[Sequence, int], list[bool]] | None = None,
) -> None:
    """The env's contact flag per state (``ours``: its one colliding copy standing on the
    nearest obstacle) against ``model``, where every obstacle collides: equal to MJX's own
    collision on ``model`` at every state (the same routine: the copy must stand where the
    obstacle is), and that to native MuJoCo's at every state but where native's contact is
    within :data:`SHALLOW` of zero distance; native touches on ``at_least`` states.
    ``touches``: :func:`mjx_touches` of ``model``, to reuse its compile across calls."""
    closest = native_touches(model, states, geom)
    native = [d <= 0.0 for d in closest]
    theirs = (touches or mjx_touches(model))(states, geom)
    assert list(ours) == theirs, (list(ours), theirs)
    assert sum(native) >= at_least, closest
    assert all(a == b or abs(d) < SHALLOW for a, b, d in zip(theirs, native, closest)), (theirs, closest)
