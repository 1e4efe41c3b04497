"""The physics benchmark's parts, measured (``physics.py`` runs them and writes the sections).

Each measuring function returns rows (dicts) for one task: the solver sweep against the task's
reference (:class:`DmControlReference` for a dm_control port, :class:`NativeReference` for the
quadruped), throughput next to ``mujoco.rollout``, the quadruped's camera frames/s, and one
full-episode population. The caller sets the XLA device count before importing this module.
"""

from __future__ import annotations

import copy
import statistics
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from dm_control import suite as dm_control_suite
from jax.sharding import Mesh
from mujoco import rollout as native_rollout

from iap_mjx import envs
from iap_mjx.configs import distraction
from iap_mjx.envs import batch

TASKS = distraction.TASKS
QUADRUPED_TASKS = ("quadruped-flat", "quadruped-walls")


# ---- stepping and timing MJX envs -------------------------------------------------------------


def _timed(fn, *args, repeats: int):
    """Median wall time of ``repeats`` calls of an already-compiled ``fn``."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _all_devices() -> Mesh | None:
    """A mesh over every XLA device for ``batch.shard``, or ``None`` on one device."""
    devices = jax.devices()
    return Mesh(np.array(devices), (batch.BATCH_AXIS,)) if len(devices) > 1 else None


def _steps_program(env, steps: int, chunk_size: int, mesh: Mesh | None):
    """jitted ``(states, actions (B, steps, nu)) -> states`` stepping every env ``steps`` times."""

    def one_env(state, actions):
        return jax.lax.scan(lambda s, a: (env.step(s, a), None), state, actions)[0]

    run = batch.chunked_vmap(one_env, chunk_size)
    if mesh is not None:
        run = batch.shard(run, mesh)
    return jax.jit(run)


def measure_mjx(env, states, actions, chunk_size: int, mesh: Mesh | None, repeats: int):
    """(compile seconds, env-steps per second) for one batch configuration."""
    program = _steps_program(env, actions.shape[1], chunk_size, mesh)
    start = time.perf_counter()
    compiled = program.lower(states, actions).compile()
    compile_s = time.perf_counter() - start
    jax.block_until_ready(compiled(states, actions))  # warm-up
    seconds = _timed(compiled, states, actions, repeats=repeats)
    return compile_s, actions.shape[0] * actions.shape[1] / seconds


# ---- native MuJoCo ----------------------------------------------------------------------------


def native_model(name: str, env) -> mujoco.MjModel:
    """The native reference model: dm_control's for a suite task, else the env's own."""
    if name in QUADRUPED_TASKS:
        return env.mj_model
    domain, task = name.split("-")
    return dm_control_suite.load(domain, task).physics.model.ptr


def native_controls(name: str, actions) -> np.ndarray:
    """``data.ctrl`` for env actions: the quadruped's are joint targets mapped from [-1, 1]."""
    if name in QUADRUPED_TASKS:
        from iap_mjx.robots import a1

        return np.asarray(a1.action_to_targets(np.asarray(actions, np.float64)))
    return np.asarray(actions, np.float64)


def measure_native(name: str, env, states, actions, n_sub_steps: int, nthread: int, repeats: int):
    """env-steps per second of ``mujoco.rollout`` on the native model from the same states
    (qpos, qvel and, for the course, the walls' mocap positions)."""
    model = native_model(name, env)
    qpos, qvel = np.asarray(states.data.qpos), np.asarray(states.data.qvel)
    mocap = np.asarray(states.data.mocap_pos)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    data = mujoco.MjData(model)
    initial = np.empty((qpos.shape[0], mujoco.mj_stateSize(model, spec)))
    for i in range(qpos.shape[0]):
        mujoco.mj_resetData(model, data)
        data.qpos[:], data.qvel[:] = qpos[i], qvel[i]
        if model.nmocap:
            data.mocap_pos[:] = mocap[i]
        mujoco.mj_getState(model, data, initial[i], spec)
    control = np.repeat(native_controls(name, actions), n_sub_steps, axis=1)
    datas = [mujoco.MjData(model) for _ in range(nthread)]
    # nthread=1 runs on the calling thread (a pool of 0); otherwise a persistent pool.
    with native_rollout.Rollout(nthread=0 if nthread == 1 else nthread) as pool:
        pool.rollout(model, datas, initial, control)  # warm-up
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            pool.rollout(model, datas, initial, control)
            times.append(time.perf_counter() - start)
    return actions.shape[0] * actions.shape[1] / statistics.median(times)


# ---- the parts --------------------------------------------------------------------------------


def parse_setting(text: str) -> dict:
    """``"8/4/12"`` -> solver_iterations 8, ls_iterations 4, max_contacts 12 (or ``all``/``task``);
    a fourth field sets the quadruped's ``max_geom_pairs`` the same way. The quadruped's settings
    may start with its solver and leave out the slots: ``"cg/4/4"`` (contacts and pairs ``task``)."""
    fields = text.split("/")
    setting = {}
    if fields[0] in ("newton", "cg"):
        setting["solver"] = fields.pop(0)
        fields += ["task"] * (4 - len(fields))
    iterations, ls_iterations, contacts, *pairs = fields
    count = lambda v: v if v in ("all", "task") else int(v)  # noqa: E731
    setting.update(solver_iterations=int(iterations), ls_iterations=int(ls_iterations), max_contacts=count(contacts))
    if pairs:
        setting["max_geom_pairs"] = count(pairs[0])
    return setting


def solver_sweep(name: str, settings, steps: int, repeats: int, chunk_size: int) -> list[dict]:
    """Per solver setting: the errors against the task's reference (:class:`DmControlReference`
    or, for the quadruped, :class:`NativeReference`) and env-steps/s at B=256 on all devices."""
    reference = (NativeReference if name in QUADRUPED_TASKS else DmControlReference)(name, steps)
    mesh = _all_devices()
    rows = []
    for setting in settings:
        env = envs.make(name, episode_length=10 * steps, **parse_setting(setting))
        errors = reference.compare(env)
        size = 256
        states = jax.jit(batch.chunked_vmap(env.reset, min(size, chunk_size)))(
            jax.random.split(jax.random.key(0), size)
        )
        actions = jax.random.uniform(jax.random.key(1), (size, 10, env.action_size), minval=-1.0, maxval=1.0)
        _, rate = measure_mjx(env, states, actions, min(size // len(jax.devices()), chunk_size), mesh, repeats)
        rows.append(
            dict(
                task=name,
                iterations=env.config.solver_iterations,
                ls_iterations=env.config.ls_iterations,
                contacts="all" if env.max_contacts is None else env.max_contacts,
                **errors,
                rate=rate,
            )
        )
        print(rows[-1], flush=True)
    return rows


def throughput(name: str, batches, steps: int, chunk_size: int, repeats: int) -> list[dict]:
    """Per batch size: MJX on one device and on all, native with 1 and 2 threads, same states."""
    env = envs.make(name)
    rows = []
    devices = jax.devices()
    mesh = _all_devices()
    for size in batches:
        keys = jax.random.split(jax.random.key(size), size)
        states = jax.jit(batch.chunked_vmap(env.reset, min(size, chunk_size)))(keys)
        actions = jax.random.uniform(jax.random.key(1), (size, steps, env.action_size), minval=-1.0, maxval=1.0)
        chunk = min(size, chunk_size)
        one = measure_mjx(env, states, actions, chunk, None, repeats)
        share = min(size // len(devices), chunk_size)
        many = measure_mjx(env, states, actions, share, mesh, repeats) if mesh else (np.nan, np.nan)
        native = [measure_native(name, env, states, np.asarray(actions), env.n_sub_steps, t, repeats) for t in (1, 2)]
        rows.append(
            dict(
                task=name,
                batch=size,
                steps=steps,
                compile_1=one[0],
                mjx_1=one[1],
                compile_n=many[0],
                mjx_n=many[1],
                native_1=native[0],
                native_2=native[1],
            )
        )
        print(rows[-1], flush=True)
    return rows


def camera_rate(name: str, batches, repeats: int, chunk_size: int) -> list[dict]:
    """First-person frames/s (RGB at the env's default size) on states of random episodes."""
    env = envs.make(name, obs_mode="pixels")
    devices = jax.devices()
    mesh = _all_devices()
    rows = []
    for size in batches:
        states = jax.jit(batch.chunked_vmap(env.env.reset, min(size, chunk_size)))(
            jax.random.split(jax.random.key(3), size)
        )
        actions = jax.random.uniform(jax.random.key(4), (size, 20, env.action_size), minval=-0.2, maxval=0.2)
        states = _steps_program(env.env, 20, min(size, chunk_size), None)(states, actions)
        render = jax.vmap(lambda d: env.render(d))
        one = jax.jit(render)
        start = time.perf_counter()
        one = one.lower(states.data).compile()
        compile_s = time.perf_counter() - start
        jax.block_until_ready(one(states.data))
        rate_1 = size / _timed(one, states.data, repeats=repeats)
        rate_n = np.nan
        if mesh is not None and size % len(devices) == 0:
            many = jax.jit(batch.shard(render, mesh)).lower(states.data).compile()
            jax.block_until_ready(many(states.data))
            rate_n = size / _timed(many, states.data, repeats=repeats)
        cfg = env.camera.config
        rows.append(
            dict(
                task=name, batch=size, height=cfg.height, width=cfg.width, fps_1=rate_1, fps_n=rate_n, compile=compile_s
            )
        )
        print(rows[-1], flush=True)
    return rows


def long_run(name: str, size: int, chunk_size: int) -> dict:
    """One ``size`` envs x one full episode rollout, chunked and sharded, timed."""
    env = envs.make(name)
    steps = env.episode_length
    mesh = _all_devices()
    states = jax.jit(batch.chunked_vmap(env.reset, min(size, chunk_size)))(jax.random.split(jax.random.key(0), size))
    actions = jax.random.uniform(jax.random.key(2), (size, steps, env.action_size), minval=-1.0, maxval=1.0)
    program = _steps_program(env, steps, min(size // len(jax.devices()), chunk_size), mesh)
    start = time.perf_counter()
    compiled = program.lower(states, actions).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    final = jax.block_until_ready(compiled(states, actions))
    seconds = time.perf_counter() - start
    row = dict(
        task=name,
        batch=size,
        steps=steps,
        compile=compile_s,
        seconds=seconds,
        rate=size * steps / seconds,
        done=int(np.sum(np.asarray(final.done) > 0)),
        nan=int(np.sum(np.asarray(final.metrics["nan_terminations"]))),
        saturated=int(np.sum(np.asarray(final.metrics["contact_saturated"]))),
        finite=bool(np.all(np.isfinite(np.asarray(final.data.qpos)))),
    )
    print(row, flush=True)
    return row


# ---- the sweep's references -------------------------------------------------------------------


class DmControlReference:
    """dm_control's own runs of a suite task, the reference of its solver sweep.

    Three seeds from dm_control's start (float64, its Newton solver, 100 iterations), half
    uniform and half saturated actions; native's own sensitivity is the same runs restarted
    from the float32-rounded state with qvel 1 ulp up.
    """

    def __init__(self, name: str, steps: int):
        self.runs = [self._run(name, seed, steps) for seed in range(3)]
        self.native_error = statistics.median(float(np.abs(r[4] - r[5]).max()) for r in self.runs)

    @staticmethod
    def _run(name: str, seed: int, steps: int):
        """``(qpos0, qvel0, reset info, actions, final qpos, final qpos of the 1-ulp restart)``."""
        domain, task = name.split("-")
        env = dm_control_suite.load(domain, task, task_kwargs={"random": seed})
        env.reset()
        physics = env.physics
        info = {"target": physics.named.model.geom_pos["target", :2].copy()} if domain == "reacher" else {}
        qpos0, qvel0 = physics.data.qpos.copy(), physics.data.qvel.copy()
        rng = np.random.default_rng(seed)
        n_act = env.action_spec().shape[0]
        actions = np.concatenate(
            [rng.uniform(-1, 1, (steps // 2, n_act)), np.sign(rng.uniform(-1, 1, (steps - steps // 2, n_act)))]
        )
        for action in actions:
            env.step(action)
        final = physics.data.qpos.copy()
        # Native's own sensitivity: the same run from the float32-rounded start, qvel 1 ulp off.
        env.reset()
        with physics.reset_context():
            physics.data.qpos[:] = qpos0.astype(np.float32)
            physics.data.qvel[:] = np.nextafter(qvel0.astype(np.float32), np.float32(np.inf))
            if info:
                physics.named.model.geom_pos["target", :2] = info["target"]
        for action in actions:
            env.step(action)
        return qpos0, qvel0, info, actions, final, physics.data.qpos.copy()

    def compare(self, env) -> dict:
        """``error``: the median over the runs of max |qpos - dm_control's| at the end;
        ``native_error``: native's own."""
        final_qpos = jax.jit(lambda s, a: jax.lax.scan(lambda s, a: (env.step(s, a), None), s, a)[0].data.qpos)
        errors = []
        for qpos0, qvel0, info, actions, final, _ in self.runs:
            ours = final_qpos(env.reset_to(qpos0, qvel0, **info), jnp.asarray(actions, jnp.float32))
            errors.append(float(np.abs(np.asarray(ours) - final).max()))
        return dict(error=statistics.median(errors), native_error=self.native_error)


class NativeReference:
    """Native MuJoCo on the quadruped env's own model, the reference of its solver sweep.

    Three episodes from the env's own first states; PD targets the standing pose plus
    uniform +-0.3 rad (a walking-like load: the robot stays up, feet on the ground).
    """

    def __init__(self, name: str, steps: int):
        from iap_mjx.robots import a1

        self.name = name
        rng = np.random.default_rng(0)
        targets = a1.HOME_JOINTS + rng.uniform(-0.3, 0.3, (3, steps, 12))
        self.actions = np.asarray(a1.targets_to_action(targets), np.float32)

    def compare(self, env) -> dict:
        """MJX vs native on the same compiled model (``same``), vs native run to convergence
        (``converged``), native's own sensitivity (``native_error``), each the median over the
        episodes of the largest qpos gap up to the step that ended the episode; ``ended``:
        episodes the env ended early."""
        run = jax.jit(lambda s, a: jax.lax.scan(lambda s, a: (env.step(s, a),) * 2, s, a)[1])
        reset = jax.jit(env.reset)
        same, converged, own, done = [], [], [], 0
        for seed in range(3):
            first = reset(jax.random.key(seed))
            visited = run(first, jnp.asarray(self.actions[seed]))
            ours = np.asarray(visited.data.qpos)
            ended = np.asarray(visited.done) > 0
            done += int(ended[-1])
            live = np.concatenate([[True], ~ended[:-1]])  # up to the step that ended the episode
            controls = native_controls(self.name, self.actions[seed])
            theirs = _native_run(env, env.mj_model, first.data, controls)
            same.append(np.abs(ours - theirs)[live].max())
            moved = _native_run(env, env.mj_model, first.data, controls, ulp=True)
            own.append(np.abs(moved - theirs)[live].max())
            reference = _native_run(env, _accurate(env.mj_model), first.data, controls)
            converged.append(np.abs(ours - reference)[live].max())
        return dict(
            solver=env.config.solver,
            pairs="all" if env.max_geom_pairs is None else env.max_geom_pairs,
            same=statistics.median(same),
            converged=statistics.median(converged),
            native_error=statistics.median(own),
            ended=done,
        )


def _native_run(env, model: mujoco.MjModel, data0, controls: np.ndarray, ulp: bool = False) -> np.ndarray:
    """qpos after every control step of ``mujoco.mj_step`` (float64) from an env state; with
    ``ulp``, its joint angles and velocities moved 1 float32 ulp up first (native's own
    sensitivity, as the physics section measures it for dm_control). On the course, the
    colliding wall is moved after every control step as the env moves it."""
    data = mujoco.MjData(model)
    qpos = np.asarray(data0.qpos, np.float32)
    qvel = np.asarray(data0.qvel, np.float32)
    if ulp:
        qpos = np.concatenate([qpos[:7], np.nextafter(qpos[7:], np.float32(np.inf))])
        qvel = np.nextafter(qvel, np.float32(np.inf))
    data.qpos[:], data.qvel[:] = qpos, qvel
    if model.nmocap:
        data.mocap_pos[:] = np.asarray(data0.mocap_pos)
    out = []
    for ctrl in controls:
        data.ctrl[:] = ctrl
        for _ in range(env.n_sub_steps):
            mujoco.mj_step(model, data)
        if hasattr(env, "contact_wall_position"):
            data.mocap_pos[-1] = np.asarray(env.contact_wall_position(data.qpos[0], data.mocap_pos[:-1]))
        out.append(data.qpos.copy())
    return np.array(out)


def _accurate(model: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of ``model`` with MuJoCo's default solver settings (Newton, 100 iterations, 50
    line-search iterations; it converges to its tolerance well before)."""
    accurate = copy.deepcopy(model)
    accurate.opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    accurate.opt.iterations, accurate.opt.ls_iterations = 100, 50
    return accurate
