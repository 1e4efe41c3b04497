"""The physics benchmark's ``BENCHMARKS.md`` sections, written from its parts' saved rows.

``dm_control_markdown`` writes the ``physics`` section, ``quadruped_markdown`` the
``physics-quadruped`` one; both take ``{part: rows}`` (an empty list for a part not saved) and
the command line's ``args`` (``args.runs``: each saved part's command, time, ``XLA_FLAGS``,
chunk size and load).
"""

from __future__ import annotations

import os
import platform

import jax
import mujoco
import numpy as np

from iap_mjx import envs

# ---- the sections: shared tables --------------------------------------------------------------


def _machine() -> str:
    return (
        f"{platform.processor() or platform.machine()}, {jax.device_count()} XLA CPU devices, "
        f"jax {jax.__version__}, mujoco {mujoco.__version__}"
    )


def _part_commands(args) -> list[str]:
    """One line per saved part: its command, when, ``XLA_FLAGS`` and the load around it."""
    return [
        f"- {part}: `python benchmarks/physics.py {run['argv']}` ({run['when']}; "
        f"`XLA_FLAGS={run.get('xla_flags', 'not recorded')}`; 1-min load average "
        f"{run['load_before']:.1f} before, {run['load_after']:.1f} after)"
        for part, run in args.runs.items()
    ]


THROUGHPUT_COLUMNS = [
    "| task | B | MJX 1 dev | MJX all dev | native 1 thr | native 2 thr | ratio | compile 1 dev / all |",
    "|---|---|---|---|---|---|---|---|",
]


def _throughput_rows(rows) -> list[str]:
    return [
        f"| {r['task']} | {r['batch']} | {r['mjx_1']:,.0f} | {r['mjx_n']:,.0f} | {r['native_1']:,.0f} | "
        f"{r['native_2']:,.0f} | {r['mjx_n'] / r['native_2']:.2f} | {r['compile_1']:.0f} / {r['compile_n']:.0f} |"
        for r in rows
    ]


LONG_COLUMNS = [
    "| task | B | control steps | compile s | wall s | env-steps/s | done | nan | saturated | qpos finite |",
    "|---|---|---|---|---|---|---|---|---|---|",
]


def _long_rows(rows) -> list[str]:
    return [
        f"| {r['task']} | {r['batch']} | {r['steps']} | {r['compile']:.0f} | {r['seconds']:.1f} | "
        f"{r['rate']:,.0f} | {r['done']} | {r['nan']} | {r['saturated']} | {r['finite']} |"
        for r in rows
    ]


# ---- the dm_control section -------------------------------------------------------------------


def dm_control_markdown(parts: dict[str, list[dict]], args) -> str:
    sweep_rows, rows, long_rows = parts["sweep"], parts["throughput"], parts["long"]
    lines = [
        "## Physics: MJX task ports vs native MuJoCo",
        "",
        f"Machine: {_machine()}. The machine is shared, so compare numbers within a row (measured back "
        "to back), not across runs. Each part's command, with the `XLA_FLAGS` it ran with:",
        "",
        *_part_commands(args),
    ]
    if sweep_rows:
        lines += [
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
            + ", ".join(f"{n} {_default_setting(n)}" for n in dict.fromkeys(r["task"] for r in sweep_rows))
            + ".",
            "",
            "| task | iterations / ls / contacts | qpos error | native's own | env-steps/s |",
            "|---|---|---|---|---|",
        ]
        for r in sweep_rows:
            lines.append(
                f"| {r['task']} | {r['iterations']} / {r['ls_iterations']} / {r['contacts']} | "
                f"{r['error']:.1e} | {r['native_error']:.1e} | {r['rate']:,.0f} |"
            )
    if rows:
        chunk = args.runs["throughput"].get("chunk_size", args.chunk_size)
        lines += [
            "",
            f"### Throughput ({rows[0]['steps']} control steps per call, env-steps/s = envs x control steps / s)",
            "",
            "MJX: 1 device = one XLA CPU device, chunks of <= "
            f"{chunk} envs (`lax.map`); {jax.device_count()} dev = `shard_map` over "
            f"{jax.device_count()} devices. Native: `mujoco.rollout` on dm_control's model "
            "(float64, its own solver settings), same states and actions, 1 and 2 threads. "
            "ratio = MJX on all devices / native with 2 threads. Compile = XLA compile time (s).",
            "",
            *THROUGHPUT_COLUMNS,
            *_throughput_rows(rows),
        ]
    if long_rows:
        lines += [
            "",
            "### A full population: B envs x 1000 control steps in one call",
            "",
            "Chunked (`lax.map`) and sharded (`shard_map`) over all devices, random actions, "
            "steady state (compiled first). done = envs ended, nan = ended by a bad state, "
            "saturated = envs that ever filled every contact slot.",
            "",
            *LONG_COLUMNS,
            *_long_rows(long_rows),
        ]
    return "\n".join(lines) + "\n"


def _default_setting(name: str) -> str:
    env = envs.make(name)
    contacts = "all" if env.max_contacts is None else env.max_contacts
    return f"{env.config.solver_iterations} / {env.config.ls_iterations} / {contacts}"


# ---- the quadruped section --------------------------------------------------------------------


def quadruped_markdown(parts: dict[str, list[dict]], args) -> str:
    sweep_rows, rows, long_rows, camera_rows = parts["sweep"], parts["throughput"], parts["long"], parts["camera"]
    walls = [r for r in rows if r["task"] == "quadruped-walls" and r["batch"] == 256]
    cam = [r for r in camera_rows if r["batch"] == 256]
    lines = [
        "## Physics: the A1-class quadruped (MJX vs native MuJoCo on the same model)",
        "",
        f"Machine: {_machine()}, {os.cpu_count()} cores. Each part measured "
        "by its own command, alone on the machine, with the "
        "`XLA_FLAGS` it ran with:",
        "",
        *_part_commands(args),
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
    missing = [
        name
        for part, name in (
            ("sweep", "the solver sweep"),
            ("throughput", "the throughput table"),
            ("long", "the full-length random-action episodes"),
            ("camera", "the camera rows"),
        )
        if part not in args.runs
    ]
    if missing:
        lines[-1:-1] = [f"Not measured yet: {', '.join(missing)}.", ""]
    if walls:
        lines.append(
            f"- `quadruped-walls` at B=256 on both cores: **{walls[0]['mjx_n']:,.0f}** control steps/s "
            f"(bar 4,000: {'met' if walls[0]['mjx_n'] >= 4000 else 'not met'}); walls, foot and wall contacts on."
        )
    if cam:
        lines.append(
            f"- first-person camera at its default {cam[0]['width']}x{cam[0]['height']} RGB, B=256: "
            f"**{np.nanmax([cam[0]['fps_1'], cam[0]['fps_n']]):,.0f}** frames/s "
            f"(bar 10,000: {'met' if np.nanmax([cam[0]['fps_1'], cam[0]['fps_n']]) >= 10000 else 'not met'})."
        )
    for r in long_rows:
        lines.append(
            f"- {r['batch']} random-action episodes of `{r['task']}`, full length ({r['steps']} control steps): "
            f"**{r['nan']}** ended by NaN or a bad state; qpos finite: {r['finite']}."
        )
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
            lines.append(
                f"| {r['task']} | {r.get('solver', 'newton')} / {r['iterations']} / {r['ls_iterations']} / "
                f"{r['contacts']} / {r['pairs']} | "
                f"{r['same']:.1e} | {r['converged']:.1e} | {r['native_error']:.1e} | {r['ended']} | {r['rate']:,.0f} |"
            )
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
            *THROUGHPUT_COLUMNS,
            *_throughput_rows(rows),
        ]
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
            lines.append(
                f"| {r['width']}x{r['height']} | {r['batch']} | {r['fps_1']:,.0f} | {r['fps_n']:,.0f} | {r['compile']:.1f} |"
            )
        lines += [
            "",
            "The camera rows have no baseline measured in the same run (`benchmarks/camera.py`'s "
            "MuJoCo-renderer column covers the dm_control tasks only).",
        ]
    if long_rows:
        lines += [
            "",
            "### Full-length random-action episodes",
            "",
            "One chunked, sharded call; uniform random actions in [-1, 1] (joint targets anywhere in their ranges). "
            "done = episodes ended (time limit, fall, or bad state); nan = ended by a bad state (NaN or "
            "|qpos|, |qvel| > max_abs_state); saturated = episodes that ever filled every contact slot or culled pair.",
            "",
            *LONG_COLUMNS,
            *_long_rows(long_rows),
        ]
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
    text = (
        f"The choice, as for the dm_control tasks: the fastest setting whose error stays at the float32 level of "
        f"a converged solve. Settings within 2x of the smallest error against native at MuJoCo's defaults "
        f"({floor:.1e}): {', '.join(name(r) for r in accepted)}. Rates within 10% of the fastest of them "
        f"({fastest:,.0f} env-steps/s) count as equal (this machine's run-to-run spread); among those, the "
        f"smallest iteration budget: **{name(pick)}**."
    )
    if rejected:
        ratios = [r["converged"] / floor for r in rejected]
        text += (
            f" The other settings leave the solve unconverged: their error is {min(ratios):,.0f}x to "
            f"{max(ratios):,.0f}x larger ({', '.join(name(r) for r in rejected)})."
        )
    text += (
        f" The env runs **{env}** (`iap_mjx.robots.a1`: `SOLVER`, `ITERATIONS`, `LS_ITERATIONS`, in its "
        f"MJCF's `<option>`)" + ("." if env == name(pick) else ", NOT the pick above.")
    )
    return text
