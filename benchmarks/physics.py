"""Physics throughput of the MJX task ports next to native MuJoCo, and the solver sweep.

Writes the ``physics`` section of ``BENCHMARKS.md``:

1. Solver settings: for each task in ``--sweep-tasks`` and each ``--sweep`` setting
   ``ITERATIONS/LS_ITERATIONS/CONTACTS`` (contact slots: ``EnvConfig.max_contacts``), the
   largest qpos error against dm_control (float64, Newton, 100 iterations) after
   ``--sweep-steps`` control steps from dm_control's own start (half uniform, half saturated
   actions; median over 3 seeds), next to native MuJoCo's own sensitivity (dm_control
   restarted from the float32-rounded state, 1 ulp off in qvel), and the env-steps/s at
   B=256 on all devices.
2. Throughput: env-steps/s (control steps x envs / s, steady state) per task at each B
   in ``--batch``, on one XLA device and on all (``shard_map``), next to
   ``mujoco.rollout`` with 1 and 2 threads on dm_control's model running the same
   number of physics steps from the same states, measured in the same run; compile
   time separately.
3. A full population: ``--long-batch`` envs x 1000 control steps in one chunked, sharded
   call per task in ``--long-tasks``, with its wall-clock and how many envs ended.

Run (heavy; serialise with the other benchmarks):

    python benchmarks/physics.py

``--quadruped`` measures our A1-class quadruped instead (``quadruped-flat``,
``quadruped-walls``) and writes the ``physics-quadruped`` section: the same three parts with
native MuJoCo (``mujoco.mj_step``/``mujoco.rollout``, float64) on the env's own compiled model
as the reference (there is no dm_control task), plus the first-person camera's frames/s.
Its parts (``--parts sweep throughput camera long``) can be measured one per command, each
saving its rows to ``--rows-dir`` (``benchmarks/physics-quadruped/<part>.json``, with its
command, time and load); the section is written from every part saved there:

    python benchmarks/physics.py --quadruped --parts sweep --no-write
    ...
    python benchmarks/physics.py --quadruped --parts   # no measuring: writes the section

The quadruped's envs are vmapped in chunks of ``--chunk-size`` (default 32: faster than 64 on
this machine, measured) per device, at most
the env's ``max_chunk_size`` (102): with jaxlib 0.10, a larger vmapped batch of quadrupeds
sharded over both devices deadlocks XLA:CPU at its first execution (every thread parked on a
futex: the two intra-op pool threads each block in a batched LAPACK Cholesky waiting for tasks
queued on that same pool; see ``iap_mjx.envs.dmc.serial_lapack_batch``).
``--xla_cpu_multi_thread_eigen=false`` does not avoid it (the LAPACK kernels use XLA's intra-op
pool, not Eigen's) and is not set.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

from iap_mjx import runtime

DEVICE_COUNT = runtime.set_host_device_count(2)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from dm_control import suite  # noqa: E402
from jax.sharding import Mesh  # noqa: E402
from mujoco import rollout as native_rollout  # noqa: E402

from iap_mjx import envs  # noqa: E402
from iap_mjx.envs import batch  # noqa: E402

SECTION = "physics"
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import report  # noqa: E402
TASKS = ("cheetah-run", "walker-walk", "cartpole-swingup", "ball_in_cup-catch", "reacher-easy", "finger-spin")
QUADRUPED_TASKS = ("quadruped-flat", "quadruped-walls")


def _timed(fn, *args, repeats: int):
    """Median wall time of ``repeats`` calls of an already-compiled ``fn``."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return statistics.median(times)


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


def native_model(name: str, env) -> mujoco.MjModel:
    """The native reference model: dm_control's for a suite task, else the env's own."""
    if name in QUADRUPED_TASKS:
        return env.mj_model
    domain, task = name.split("-")
    return suite.load(domain, task).physics.model.ptr


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


def throughput(name: str, batches, steps: int, chunk_size: int, repeats: int) -> list[dict]:
    env = envs.make(name)
    rows = []
    devices = jax.devices()
    mesh = Mesh(np.array(devices), (batch.BATCH_AXIS,)) if len(devices) > 1 else None
    for size in batches:
        keys = jax.random.split(jax.random.key(size), size)
        states = jax.jit(batch.chunked_vmap(env.reset, min(size, chunk_size)))(keys)
        actions = jax.random.uniform(
            jax.random.key(1), (size, steps, env.action_size), minval=-1.0, maxval=1.0
        )
        chunk = min(size, chunk_size)
        one = measure_mjx(env, states, actions, chunk, None, repeats)
        share = min(size // len(devices), chunk_size)
        many = measure_mjx(env, states, actions, share, mesh, repeats) if mesh else (np.nan, np.nan)
        native = [
            measure_native(name, env, states, np.asarray(actions), env.n_sub_steps, t, repeats)
            for t in (1, 2)
        ]
        rows.append(
            dict(task=name, batch=size, steps=steps, compile_1=one[0], mjx_1=one[1], compile_n=many[0],
                 mjx_n=many[1], native_1=native[0], native_2=native[1])
        )
        print(rows[-1], flush=True)
    return rows


def _dm_reference(name: str, seed: int, steps: int):
    domain, task = name.split("-")
    env = suite.load(domain, task, task_kwargs={"random": seed})
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
    setting.update(solver_iterations=int(iterations), ls_iterations=int(ls_iterations),
                   max_contacts=count(contacts))
    if pairs:
        setting["max_geom_pairs"] = count(pairs[0])
    return setting


def solver_sweep(name: str, settings, steps: int, repeats: int) -> list[dict]:
    references = [_dm_reference(name, seed, steps) for seed in range(3)]
    native_err = statistics.median(float(np.abs(r[4] - r[5]).max()) for r in references)
    rows = []
    devices = jax.devices()
    mesh = Mesh(np.array(devices), (batch.BATCH_AXIS,)) if len(devices) > 1 else None
    for setting in settings:
        env = envs.make(name, **parse_setting(setting))
        final_qpos = jax.jit(
            lambda s, a: jax.lax.scan(lambda s, a: (env.step(s, a), None), s, a)[0].data.qpos
        )
        errors = []
        for qpos0, qvel0, info, actions, final, _ in references:
            ours = final_qpos(env.reset_to(qpos0, qvel0, **info), jnp.asarray(actions, jnp.float32))
            errors.append(float(np.abs(np.asarray(ours) - final).max()))
        size = 256
        states = jax.jit(batch.chunked_vmap(env.reset, 128))(jax.random.split(jax.random.key(0), size))
        actions = jax.random.uniform(jax.random.key(1), (size, 10, env.action_size), minval=-1.0, maxval=1.0)
        _, rate = measure_mjx(env, states, actions, size // len(devices), mesh, repeats)
        config = env.config
        rows.append(dict(task=name, iterations=config.solver_iterations,
                         ls_iterations=config.ls_iterations,
                         contacts="all" if env.max_contacts is None else env.max_contacts,
                         error=statistics.median(errors), native_error=native_err, rate=rate))
        print(rows[-1], flush=True)
    return rows


def long_run(name: str, size: int, steps: int, chunk_size: int) -> dict:
    """One ``size`` envs x ``steps`` control steps rollout, chunked and sharded, timed."""
    env = envs.make(name, episode_length=steps)
    devices = jax.devices()
    mesh = Mesh(np.array(devices), (batch.BATCH_AXIS,)) if len(devices) > 1 else None
    states = jax.jit(batch.chunked_vmap(env.reset, min(size, chunk_size)))(
        jax.random.split(jax.random.key(0), size)
    )
    actions = jax.random.uniform(jax.random.key(2), (size, steps, env.action_size), minval=-1.0, maxval=1.0)
    program = _steps_program(env, steps, min(size // len(devices), chunk_size), mesh)
    start = time.perf_counter()
    compiled = program.lower(states, actions).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    final = jax.block_until_ready(compiled(states, actions))
    seconds = time.perf_counter() - start
    row = dict(task=name, batch=size, steps=steps, compile=compile_s, seconds=seconds,
               rate=size * steps / seconds, done=int(np.sum(np.asarray(final.done) > 0)),
               nan=int(np.sum(np.asarray(final.metrics["nan_terminations"]))),
               saturated=int(np.sum(np.asarray(final.metrics["contact_saturated"]))),
               finite=bool(np.all(np.isfinite(np.asarray(final.data.qpos)))))
    print(row, flush=True)
    return row


def _markdown(sweep_rows, rows, long_rows, args) -> str:
    lines = [
        "## Physics: MJX task ports vs native MuJoCo",
        "",
        f"Command: `python benchmarks/physics.py {args.argv}`".rstrip() + "  ",
        f"Machine: {platform.processor() or platform.machine()}, {jax.device_count()} XLA CPU "
        f"devices, jax {jax.__version__}, mujoco {mujoco.__version__}. One run; the machine is "
        "shared, so compare numbers within a row (measured back to back), not across runs.",
        "",
        "### Solver settings (iterations / line-search iterations / contact slots)",
        "",
        f"qpos error = max |qpos - dm_control qpos| after {args.sweep_steps} control steps from "
        "dm_control's start (half uniform, half saturated actions; median of 3 seeds). "
        "native = dm_control itself restarted from the float32-rounded state with qvel 1 ulp off. "
        "Rate: env-steps/s at B=256 on all devices.",
        "",
        "Contact slots: MJX's `max_contact_points` (`EnvConfig.max_contacts`); `all` keeps a "
        "row block for every candidate geom pair. Defaults: "
        + ", ".join(f"{n} {_default_setting(n)}" for n in args.sweep_tasks) + ".",
        "",
        "| task | iterations / ls / contacts | qpos error | native's own | env-steps/s |",
        "|---|---|---|---|---|",
    ]
    for r in sweep_rows:
        lines.append(
            f"| {r['task']} | {r['iterations']} / {r['ls_iterations']} / {r['contacts']} | "
            f"{r['error']:.1e} | {r['native_error']:.1e} | {r['rate']:,.0f} |"
        )
    lines += [
        "",
        f"### Throughput ({args.steps} control steps per call, env-steps/s = envs x control steps / s)",
        "",
        "MJX: 1 device = one XLA CPU device, chunks of <= "
        f"{args.chunk_size} envs (`lax.map`); {jax.device_count()} dev = `shard_map` over "
        f"{jax.device_count()} devices. Native: `mujoco.rollout` on dm_control's model "
        "(float64, its own solver settings), same states and actions, 1 and 2 threads. "
        "ratio = MJX on all devices / native with 2 threads. Compile = XLA compile time (s).",
        "",
        "| task | B | MJX 1 dev | MJX all dev | native 1 thr | native 2 thr | ratio | compile 1 dev / all |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['task']} | {r['batch']} | {r['mjx_1']:,.0f} | {r['mjx_n']:,.0f} | "
            f"{r['native_1']:,.0f} | {r['native_2']:,.0f} | {r['mjx_n'] / r['native_2']:.2f} | "
            f"{r['compile_1']:.0f} / {r['compile_n']:.0f} |"
        )
    if long_rows:
        lines += [
            "",
            "### A full population: B envs x 1000 control steps in one call",
            "",
            "Chunked (`lax.map`) and sharded (`shard_map`) over all devices, random actions, "
            "steady state (compiled first). done = envs ended, nan = ended by a bad state, "
            "saturated = envs that ever filled every contact slot.",
            "",
            "| task | B | control steps | compile s | wall s | env-steps/s | done | nan | saturated | qpos finite |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in long_rows:
            lines.append(
                f"| {r['task']} | {r['batch']} | {r['steps']} | {r['compile']:.0f} | {r['seconds']:.1f} | "
                f"{r['rate']:,.0f} | {r['done']} | {r['nan']} | {r['saturated']} | {r['finite']} |"
            )
    return "\n".join(lines) + "\n"


def _default_setting(name: str) -> str:
    env = envs.make(name)
    contacts = "all" if env.max_contacts is None else env.max_contacts
    return f"{env.config.solver_iterations} / {env.config.ls_iterations} / {contacts}"



# ---- the quadruped: native MuJoCo on the env's own model is the reference ----------------


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


def quadruped_sweep(name: str, settings, steps: int, repeats: int, chunk_size: int) -> list[dict]:
    """Per solver setting: MJX vs native on the same compiled model (``same``), vs native
    run to convergence (``converged``), native's own sensitivity, and env-steps/s at B=256.

    Three episodes from the env's own first states; PD targets the standing pose plus
    uniform +-0.3 rad (a walking-like load: the robot stays up, feet on the ground)."""
    from iap_mjx.robots import a1

    rng = np.random.default_rng(0)
    targets = a1.HOME_JOINTS + rng.uniform(-0.3, 0.3, (3, steps, 12))
    actions = np.asarray(a1.targets_to_action(targets), np.float32)
    rows = []
    devices = jax.devices()
    mesh = Mesh(np.array(devices), (batch.BATCH_AXIS,)) if len(devices) > 1 else None
    for setting in settings:
        env = envs.make(name, episode_length=10 * steps, **parse_setting(setting))
        run = jax.jit(lambda s, a: jax.lax.scan(lambda s, a: (env.step(s, a),) * 2, s, a)[1])
        reset = jax.jit(env.reset)
        same, converged, own, done = [], [], [], 0
        for seed in range(3):
            first = reset(jax.random.key(seed))
            visited = run(first, jnp.asarray(actions[seed]))
            ours = np.asarray(visited.data.qpos)
            ended = np.asarray(visited.done) > 0
            done += int(ended[-1])
            live = np.concatenate([[True], ~ended[:-1]])  # up to the step that ended the episode
            controls = native_controls(name, actions[seed])
            theirs = _native_run(env, env.mj_model, first.data, controls)
            same.append(np.abs(ours - theirs)[live].max())
            moved = _native_run(env, env.mj_model, first.data, controls, ulp=True)
            own.append(np.abs(moved - theirs)[live].max())
            reference = _native_run(env, _accurate(env.mj_model), first.data, controls)
            converged.append(np.abs(ours - reference)[live].max())
        size = 256
        states = jax.jit(batch.chunked_vmap(env.reset, chunk_size))(jax.random.split(jax.random.key(0), size))
        random_actions = jax.random.uniform(jax.random.key(1), (size, 10, env.action_size), minval=-1.0, maxval=1.0)
        _, rate = measure_mjx(env, states, random_actions, min(size // len(devices), chunk_size), mesh, repeats)
        rows.append(dict(task=name, solver=env.config.solver, iterations=env.config.solver_iterations,
                         ls_iterations=env.config.ls_iterations,
                         contacts="all" if env.max_contacts is None else env.max_contacts,
                         pairs="all" if env.max_geom_pairs is None else env.max_geom_pairs,
                         same=statistics.median(same), converged=statistics.median(converged),
                         native_error=statistics.median(own), ended=done, rate=rate))
        print(rows[-1], flush=True)
    return rows


def camera_rate(name: str, batches, repeats: int, chunk_size: int) -> list[dict]:
    """First-person frames/s (RGB at the env's default size) on states of random episodes."""
    env = envs.make(name, obs_mode="pixels")
    devices = jax.devices()
    mesh = Mesh(np.array(devices), (batch.BATCH_AXIS,)) if len(devices) > 1 else None
    rows = []
    for size in batches:
        states = jax.jit(batch.chunked_vmap(env.env.reset, min(size, chunk_size)))(
            jax.random.split(jax.random.key(3), size))
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
        rows.append(dict(task=name, batch=size, height=cfg.height, width=cfg.width, fps_1=rate_1, fps_n=rate_n,
                         compile=compile_s))
        print(rows[-1], flush=True)
    return rows


def _quadruped_markdown(sweep_rows, rows, long_rows, camera_rows, args) -> str:
    walls = [r for r in rows if r["task"] == "quadruped-walls" and r["batch"] == 256]
    cam = [r for r in camera_rows if r["batch"] == 256]
    lines = [
        "## Physics: the A1-class quadruped (MJX vs native MuJoCo on the same model)",
        "",
        f"Machine: {platform.processor() or platform.machine()}, {jax.device_count()} XLA CPU devices, "
        f"jax {jax.__version__}, mujoco {mujoco.__version__}, {os.cpu_count()} cores. Each part measured "
        "by its own command, alone on the machine, with the "
        "`XLA_FLAGS` it ran with:",
        "",
        *[f"- {part}: `python benchmarks/physics.py {run['argv']}` ({run['when']}; "
          f"`XLA_FLAGS={run.get('xla_flags', 'not recorded')}`; 1-min load average "
          f"{run['load_before']:.1f} before, {run['load_after']:.1f} after)" for part, run in args.runs.items()],
        "",
        "The physics parts vmap at most "
        f"{max([run.get('chunk_size', args.chunk_size) for part, run in args.runs.items() if part != 'camera'] or [args.chunk_size])} "
        "envs together per device (`lax.map` over chunks): "
        "with jaxlib 0.10, 103 or more quadrupeds vmapped together per device, sharded over both devices, "
        "deadlock XLA:CPU at the first execution (each intra-op pool thread blocks in a batched LAPACK "
        "Cholesky waiting for tasks queued on that pool; `iap_mjx.envs.dmc.serial_lapack_batch`). "
        "`--xla_cpu_multi_thread_eigen=false` does not avoid it, nor does the CG solver: MJX factors the "
        "mass matrix with the same Cholesky (`smooth.factor_m`, also for the Euler integrator's implicit "
        "damping), Newton only adds its Hessian's (the lowered CG step still calls `lapack_spotrf`).",
        "",
        "Bars (issue 15), from these runs:",
    ]
    missing = [name for part, name in (("sweep", "the solver sweep"), ("throughput", "the throughput table"),
                                       ("long", "the full-length random-action episodes"),
                                       ("camera", "the camera rows")) if part not in args.runs]
    if missing:
        lines[-1:-1] = [f"Not measured yet: {', '.join(missing)}.", ""]
    if walls:
        lines.append(f"- `quadruped-walls` at B=256 on both cores: **{walls[0]['mjx_n']:,.0f}** control steps/s "
                     f"(bar 4,000: {'met' if walls[0]['mjx_n'] >= 4000 else 'not met'}); walls, foot and wall contacts on.")
    if cam:
        lines.append(f"- first-person camera at its default {cam[0]['width']}x{cam[0]['height']} RGB, B=256: "
                     f"**{np.nanmax([cam[0]['fps_1'], cam[0]['fps_n']]):,.0f}** frames/s "
                     f"(bar 10,000: {'met' if np.nanmax([cam[0]['fps_1'], cam[0]['fps_n']]) >= 10000 else 'not met'}).")
    for r in long_rows:
        lines.append(f"- {r['batch']} random-action episodes of `{r['task']}`, full length ({r['steps']} control steps): "
                     f"**{r['nan']}** ended by NaN or a bad state; qpos finite: {r['finite']}.")
    if sweep_rows:
        lines += [
            "",
            "### Solver settings (solver / iterations / line-search iterations / contact slots / geom pairs)",
            "",
            f"qpos error = max |qpos gap| over {args.sweep_steps} control steps from the env's first state, median of 3 "
            "episodes, PD targets = standing pose + uniform +-0.3 rad, walls on. same = native `mujoco.mj_step` (float64) "
            "on the same compiled model (same solver settings): float32 noise is what should remain. converged = native "
            "at MuJoCo's defaults (Newton, 100 / 50 iterations). native's own = native on the same model restarted with its joint "
            "angles and velocities 1 float32 ulp up (as the physics section measures dm_control's). Episodes the env "
            "ended early (a fall; ended, of 3) are compared up to that step. Rate: env-steps/s at B=256, "
            "uniform random actions, all devices.",
            "",
            "| task | solver / iterations / ls / contacts / pairs | vs native, same model | vs native, converged | native's own | ended | env-steps/s |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in sweep_rows:
            lines.append(f"| {r['task']} | {r.get('solver', 'newton')} / {r['iterations']} / {r['ls_iterations']} / "
                         f"{r['contacts']} / {r['pairs']} | "
                         f"{r['same']:.1e} | {r['converged']:.1e} | {r['native_error']:.1e} | {r['ended']} | {r['rate']:,.0f} |")
        lines += ["", _solver_choice(sweep_rows)]
    if rows:
        lines += [
            "",
            f"### Throughput ({rows[0].get('steps', args.steps)} control steps per call, uniform random actions)",
            "",
            "env-steps/s = envs x control steps / s (one control step = 5 physics steps). MJX on 1 device "
            f"and on {jax.device_count()} (`shard_map`); native = `mujoco.rollout` on the env's own model (float64, "
            "same solver settings), same states and controls, 1 and 2 threads. ratio = MJX all devices / native 2 threads. "
            "The course has one colliding wall, `wall_contact`, which the env keeps on the wall nearest the trunk "
            "(`QuadrupedWalls.contact_wall_position`; the seen walls do not collide): MJX collides the feet with the "
            "platform (4 sphere-box pairs) and the robot with that wall (trunk 1 box-box, thighs and calves 8 "
            "capsule-box, feet 4 sphere-box pairs), and keeps the 8 nearest wall contacts. In `mujoco.rollout` the "
            "colliding wall stays where the env put it at the start: in 20 control steps from there the trunk cannot "
            "reach where the env would move it (0.95 m or more from the first wall).",
            "",
            "| task | B | MJX 1 dev | MJX all dev | native 1 thr | native 2 thr | ratio | compile 1 dev / all |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in rows:
            lines.append(f"| {r['task']} | {r['batch']} | {r['mjx_1']:,.0f} | {r['mjx_n']:,.0f} | {r['native_1']:,.0f} | "
                         f"{r['native_2']:,.0f} | {r['mjx_n'] / r['native_2']:.2f} | {r['compile_1']:.0f} / {r['compile_n']:.0f} |")
    if camera_rows:
        lines += [
            "",
            "### First-person camera (`quadruped-walls`, `obs_mode=pixels`)",
            "",
            "`Camera.render` RGB frames/s, steady state, states after 20 control steps of small random actions; "
            "the robot's own geoms are not drawn.",
            "",
            "| size | B | 1 device | all devices | compile s |",
            "|---|---|---|---|---|",
        ]
        for r in camera_rows:
            lines.append(f"| {r['width']}x{r['height']} | {r['batch']} | {r['fps_1']:,.0f} | {r['fps_n']:,.0f} | {r['compile']:.1f} |")
        lines += ["", "The camera rows have no baseline measured in the same run (`benchmarks/camera.py`'s "
                  "MuJoCo-renderer column covers the dm_control tasks only)."]
    if long_rows:
        lines += [
            "",
            "### Full-length random-action episodes",
            "",
            "One chunked, sharded call; uniform random actions in [-1, 1] (joint targets anywhere in their ranges). "
            "done = episodes ended (time limit, fall, or bad state); nan = ended by a bad state (NaN or "
            "|qpos|, |qvel| > max_abs_state); saturated = episodes that ever filled every contact slot or culled pair.",
            "",
            "| task | B | control steps | compile s | wall s | env-steps/s | done | nan | saturated | qpos finite |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in long_rows:
            lines.append(f"| {r['task']} | {r['batch']} | {r['steps']} | {r['compile']:.0f} | {r['seconds']:.1f} | "
                         f"{r['rate']:,.0f} | {r['done']} | {r['nan']} | {r['saturated']} | {r['finite']} |")
    return "\n".join(lines) + "\n"


def _solver_choice(sweep_rows) -> str:
    """The rule that picks the quadruped's solver settings from the sweep, applied to its rows,
    next to what the env runs (``iap_mjx.robots.a1``, its MJCF's ``<option>``)."""
    from iap_mjx.robots import a1

    floor = min(r["converged"] for r in sweep_rows)
    accepted = [r for r in sweep_rows if r["converged"] <= 2 * floor]
    rejected = [r for r in sweep_rows if r["converged"] > 2 * floor]
    name = lambda r: f"{r.get('solver', 'newton')} {r['iterations']} / {r['ls_iterations']}"  # noqa: E731
    fastest = max(r["rate"] for r in accepted)
    tied = [r for r in accepted if r["rate"] >= 0.9 * fastest]
    pick = min(tied, key=lambda r: (r["iterations"], r["ls_iterations"]))
    env = f"{a1.SOLVER} {a1.ITERATIONS} / {a1.LS_ITERATIONS}"
    text = (f"The choice, as for the dm_control tasks: the fastest setting whose error stays at the float32 level of "
            f"a converged solve. Settings within 2x of the smallest error against native at MuJoCo's defaults "
            f"({floor:.1e}): {', '.join(name(r) for r in accepted)}. Rates within 10% of the fastest of them "
            f"({fastest:,.0f} env-steps/s) count as equal (this machine's run-to-run spread); among those, the "
            f"smallest iteration budget: **{name(pick)}**.")
    if rejected:
        ratios = [r["converged"] / floor for r in rejected]
        text += (f" The other settings leave the solve unconverged: their error is {min(ratios):,.0f}x to "
                 f"{max(ratios):,.0f}x larger ({', '.join(name(r) for r in rejected)}).")
    text += (f" The env runs **{env}** (`iap_mjx.robots.a1`: `SOLVER`, `ITERATIONS`, `LS_ITERATIONS`, in its "
             f"MJCF's `<option>`)" + ("." if env == name(pick) else f", NOT the pick above."))
    return text


QUADRUPED_PARTS = ("sweep", "throughput", "camera", "long")


def main_quadruped(args) -> None:
    """Measures ``args.parts`` and writes the section from every part's rows saved so far in
    ``--rows-dir`` (one JSON file per part, with the command and load that produced it), so the
    parts can be measured in separate, shorter holds of the exclusive CPU lock."""
    rows_dir = Path(args.rows_dir)
    rows_dir.mkdir(parents=True, exist_ok=True)
    load_before = os.getloadavg()[0]
    measure = {
        "sweep": lambda: [row for name in args.sweep_tasks
                          for row in quadruped_sweep(name, args.sweep, args.sweep_steps, args.repeats, args.chunk_size)],
        "throughput": lambda: [row for name in args.tasks
                               for row in throughput(name, args.batch, args.steps, args.chunk_size, args.repeats)],
        "camera": lambda: camera_rate("quadruped-walls", args.camera_batch, args.repeats, args.chunk_size),
        "long": lambda: [long_run(name, args.long_batch, envs.make(name).episode_length, args.chunk_size)
                         for name in args.long_tasks],
    }
    for part in args.parts:
        rows = measure[part]()
        record = dict(argv=args.argv, xla_flags=os.environ.get("XLA_FLAGS", ""), chunk_size=args.chunk_size,
                      load_before=load_before,
                      load_after=os.getloadavg()[0],
                      when=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), rows=rows)
        (rows_dir / f"{part}.json").write_text(json.dumps(record, indent=1, default=float))
    saved = {part: json.loads((rows_dir / f"{part}.json").read_text())
             for part in QUADRUPED_PARTS if (rows_dir / f"{part}.json").exists()}
    args.runs = {part: {k: v for k, v in record.items() if k != "rows"} for part, record in saved.items()}
    get = lambda part: saved[part]["rows"] if part in saved else []  # noqa: E731
    text = _quadruped_markdown(get("sweep"), get("throughput"), get("long"), get("camera"), args)
    print(text)
    if not args.no_write:
        report.write_section(ROOT / "BENCHMARKS.md", "physics-quadruped", text)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quadruped", action="store_true",
                        help="the quadruped tasks, their sweep and camera: section physics-quadruped")
    parser.add_argument("--tasks", nargs="+", default=None, choices=TASKS + QUADRUPED_TASKS)
    parser.add_argument("--batch", nargs="+", type=int, default=[64, 256, 1024])
    parser.add_argument("--steps", type=int, default=20, help="control steps per timed call")
    parser.add_argument("--chunk-size", type=int, default=None,
                        help="envs vmapped together per device (default 256; --quadruped: 32, at most the "
                             "env's max_chunk_size)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sweep-tasks", nargs="*", default=None, choices=TASKS + QUADRUPED_TASKS)
    parser.add_argument("--sweep", nargs="*", default=None,
                        help="solver settings ITERATIONS/LS_ITERATIONS/CONTACTS to compare "
                             "(quadruped: ITERATIONS/LS_ITERATIONS/CONTACTS/GEOM_PAIRS)")
    parser.add_argument("--long-tasks", nargs="*", default=None, choices=TASKS + QUADRUPED_TASKS,
                        help="tasks for the B=--long-batch full-episode run")
    parser.add_argument("--camera-batch", nargs="*", type=int, default=[1, 256],
                        help="quadruped: batches for the first-person camera's frames/s")
    parser.add_argument("--long-batch", type=int, default=1024)
    parser.add_argument("--sweep-steps", type=int, default=100)
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--parts", nargs="*", default=list(QUADRUPED_PARTS), choices=QUADRUPED_PARTS,
                        help="quadruped: the parts to measure now (the section shows every part saved)")
    parser.add_argument("--rows-dir", default=str(ROOT / "benchmarks" / "physics-quadruped"),
                        help="quadruped: where each part's rows are saved as <part>.json")
    args = parser.parse_args(argv)
    args.argv = " ".join(argv) if argv else ""
    if args.quadruped:
        limit = envs.make("quadruped-flat").max_chunk_size
        args.chunk_size = args.chunk_size or 32
        if limit is not None and args.chunk_size > limit:
            parser.error(f"--chunk-size {args.chunk_size}: the quadruped vmaps at most {limit} envs per device "
                         "(a larger batch deadlocks XLA:CPU; see iap_mjx.envs.dmc.serial_lapack_batch)")
        args.tasks = args.tasks or list(QUADRUPED_TASKS)
        args.sweep_tasks = ["quadruped-walls"] if args.sweep_tasks is None else args.sweep_tasks
        args.sweep = args.sweep or ["newton/1/4", "newton/2/4", "newton/4/4", "newton/8/2", "newton/8/4",
                                    "newton/8/8", "newton/100/50", "cg/8/4", "cg/16/4", "cg/100/50"]
        args.long_tasks = ["quadruped-walls"] if args.long_tasks is None else args.long_tasks
        main_quadruped(args)
        return
    args.chunk_size = args.chunk_size or 256
    args.tasks = args.tasks or list(TASKS)
    args.sweep_tasks = ["cheetah-run", "walker-walk"] if args.sweep_tasks is None else args.sweep_tasks
    args.sweep = args.sweep or ["8/8/all", "8/8/task", "4/4/task", "8/2/task", "16/2/task"]
    args.long_tasks = ["cheetah-run"] if args.long_tasks is None else args.long_tasks
    sweep_rows = [
        row
        for name in args.sweep_tasks
        for row in solver_sweep(name, args.sweep, args.sweep_steps, args.repeats)
    ]
    rows = [
        row for name in args.tasks for row in throughput(name, args.batch, args.steps, args.chunk_size, args.repeats)
    ]
    long_rows = [long_run(name, args.long_batch, 1000, args.chunk_size) for name in args.long_tasks]
    text = _markdown(sweep_rows, rows, long_rows, args)
    print(text)
    if not args.no_write:
        report.write_section(ROOT / "BENCHMARKS.md", SECTION, text)


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
