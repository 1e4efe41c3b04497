"""Camera throughput: our ray-cast RGB-D camera next to vmapped ``mjx.ray`` and MuJoCo's own
OpenGL renderer, measured in the same run.

Writes the ``camera`` section of ``BENCHMARKS.md``: RGB-D frames/s (steady state; compile
time apart) of ``Camera.render`` (an RGB image and a depth map per frame) at 64x64, 100x100
and 240x320 for B in {1, 64, 256} random states of the task, on one XLA CPU device and on
two (``shard_map`` over the batch); the same rays cast by ``jax.vmap(mjx.ray)`` (depth and
geom only, no shading) on one device; and ``mujoco.Renderer`` (software OSMesa, one process,
one frame at a time) for RGB and for depth. A second table: each of the five tasks at
100x100 and 240x320, B = 64, with MuJoCo's renderer on the same task.

Run (heavy: run it alone; needs ``libosmesa6`` for the MuJoCo column):

    python benchmarks/camera.py

``--distraction`` (``python benchmarks/camera.py --distraction``)
instead writes the ``camera-distraction`` section: per task, the 240x320
camera's frames/s with the Distracting Control Suite's three distractions on (static,
medium: perturbed pose, material colours, a background frame as the sky, the floor's alpha)
next to the same camera undistracted, measured in the same run (the bar: >= 90%).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from iap_mjx import runtime

DEVICE_COUNT = runtime.set_host_device_count(2)
runtime.hoist_large_constants()  # the background videos are an argument, not a constant

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import Mesh, NamedSharding, PartitionSpec  # noqa: E402
from mujoco import mjx  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import report  # noqa: E402

from iap_mjx.configs import distraction  # noqa: E402
from iap_mjx.render import Camera  # noqa: E402
from iap_mjx.viz import render_compare  # noqa: E402

SECTION = "camera"
DISTRACTION_SECTION = "camera-distraction"
DISTRACTION_TASKS = distraction.TASKS
RESOLUTIONS = ((64, 64), (100, 100), (240, 320))
BATCHES = (1, 64, 256)
TASKS = ("cheetah-run", "walker-walk", "cartpole-swingup", "ball_in_cup-catch", "reacher-easy")
TASK_RESOLUTIONS = ((100, 100), (240, 320))
TASK_BATCH = 64
TASK_ROUNDS = 7  # rounds of the two resolutions timed in turns (per-task table)


def _states(domain: str, task: str, n: int, seed: int):
    """``n`` dm_control states of the task as one batched ``mjx.Data`` and the model."""
    states = render_compare.suite_states(domain, task, n, seed)
    model = states[0][0]
    datas = [mjx.put_data(model, data) for _, data in states]
    return model, jax.tree.map(lambda *x: jnp.stack(x), *datas), states


def _rgbd(cam: Camera):
    """Batched ``Camera.render``: RGB ``(B, H, W, 3)`` and depth ``(B, H, W)``."""
    return jax.vmap(cam.render)


def _sharded(fn, mesh):
    spec = PartitionSpec("batch")
    return jax.shard_map(fn, mesh=mesh, in_specs=spec, out_specs=spec)


def _mjx_ray(model, cam: Camera):
    """``vmap`` over states of ``vmap`` over pixels of ``mjx.ray`` through the pixel centres."""
    mx = mjx.put_model(model)
    dirs = jnp.asarray(cam.ray_directions().reshape(-1, 3))
    cam_id = cam.config.camera_id
    shape = (cam.config.height, cam.config.width)

    def one(data):
        vecs = dirs @ data.cam_xmat[cam_id].T
        dist, geom = jax.vmap(lambda v: mjx.ray(mx, data, data.cam_xpos[cam_id], v, geomgroup=(1, 1, 1, 0, 0, 0)))(vecs)
        return dist.reshape(shape), geom.reshape(shape)

    return jax.vmap(one)


def _mujoco_renderer(domain: str, states, seconds: float, resolutions=RESOLUTIONS) -> dict:
    """MuJoCo's renderer frames/s (RGB, depth) per resolution, in an OSMesa child process."""
    request = {
        "domain": domain,
        "qpos": [np.asarray(d.qpos).tolist() for _, d in states[:16]],
        "geom_pos": np.asarray(states[0][0].geom_pos).tolist(),
        "geom_size": np.asarray(states[0][0].geom_size).tolist(),
        "resolutions": resolutions,
        "seconds": seconds,
    }
    env = dict(os.environ, MUJOCO_GL="osmesa", PYOPENGL_PLATFORM="osmesa")
    proc = subprocess.run(
        [sys.executable, __file__, "--mujoco-child"], input=json.dumps(request), env=env, capture_output=True, text=True
    )
    if proc.returncode != 0:
        return {"error": proc.stderr[-500:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _mujoco_child() -> None:
    import mujoco

    request = json.loads(sys.stdin.read())
    model = render_compare._suite_model(request["domain"])
    model.geom_pos[:] = np.asarray(request["geom_pos"])
    model.geom_size[:] = np.asarray(request["geom_size"])
    data = mujoco.MjData(model)
    result = {}
    for height, width in request["resolutions"]:
        renderer = mujoco.Renderer(model, height, width)
        rates = {}
        for mode in ("rgb", "depth"):
            if mode == "depth":
                renderer.enable_depth_rendering()
            frames, start = 0, time.perf_counter()
            while time.perf_counter() - start < request["seconds"]:
                data.qpos[:] = request["qpos"][frames % len(request["qpos"])]
                mujoco.mj_forward(model, data)
                renderer.update_scene(data, camera=0)
                renderer.render()
                frames += 1
            rates[mode] = frames / (time.perf_counter() - start)
            renderer.disable_depth_rendering()
        renderer.close()
        result[f"{height}x{width}"] = rates
    print(json.dumps(result))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="cheetah-run")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--mjx-ray-batches",
        type=int,
        nargs="*",
        default=[1, 64],
        help="batches at which vmapped mjx.ray is timed (slow at 240x320)",
    )
    parser.add_argument("--out", type=Path, default=report.ROOT / "BENCHMARKS.md")
    parser.add_argument("--distraction", action="store_true", help="write the camera-distraction section instead")
    parser.add_argument("--batch", type=int, default=64, help="states per call (--distraction)")
    parser.add_argument("--rounds", type=int, default=9, help="timing rounds per program (--distraction)")
    parser.add_argument("--mujoco-child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--from-log", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.mujoco_child:
        _mujoco_child()
        return
    if args.distraction:
        _distraction(args)
        return
    if args.from_log:  # rewrite the section from a previous run's printed rows
        import ast

        lines = [ast.literal_eval(line) for line in args.from_log.read_text().splitlines() if line.startswith("{")]
        sweep = [r for r in lines if "res" in r and "task" not in r]
        natives = [r for r in lines if "res" not in r and "task" not in r]
        per_task = [r for r in lines if "task" in r]
        _write(args, sweep, natives[0], per_task)
        return
    domain, task = args.task.split("-")
    model, batch, states = _states(domain, task, max(BATCHES), args.seed)
    mesh = Mesh(np.asarray(jax.devices()[:2]), ("batch",))
    sharding = NamedSharding(mesh, PartitionSpec("batch"))
    rows = []
    for height, width in RESOLUTIONS:
        cam = Camera(model, camera_id=0, height=height, width=width)
        for b in BATCHES:
            sub = jax.tree.map(lambda x: x[:b], batch)
            compile_1, step_1, _ = report.compile_and_time(_rgbd(cam), sub)
            row = {"res": f"{height}x{width}", "B": b, "compile": compile_1, "one": b / step_1}
            if b % len(mesh.devices) == 0 and len(jax.devices()) >= 2:
                sharded = jax.device_put(sub, sharding)
                compile_2, step_2, _ = report.compile_and_time(_sharded(_rgbd(cam), mesh), sharded)
                row["two"] = b / step_2
            if b in args.mjx_ray_batches:
                _, step_ray, _ = report.compile_and_time(_mjx_ray(model, cam), sub)
                row["mjx_ray"] = b / step_ray
            rows.append(row)
            print(row, flush=True)
    native = _mujoco_renderer(domain, states, seconds=3.0)
    print(native, flush=True)
    _write(args, rows, native, _per_task(args, mesh, sharding))


def _per_task(args, mesh, sharding) -> list[dict]:
    """Each task at ``TASK_RESOLUTIONS``, B = ``TASK_BATCH``, one and two devices, with MuJoCo's
    renderer on the same task."""
    rows = []
    for task in TASKS:
        domain, name = task.split("-")
        model, batch, states = _states(domain, name, TASK_BATCH, args.seed)
        native = _mujoco_renderer(domain, states, seconds=2.0, resolutions=TASK_RESOLUTIONS)
        placed = jax.device_put(batch, sharding)
        task_rows, two_device = [], []
        for height, width in TASK_RESOLUTIONS:
            cam = Camera(model, camera_id=0, height=height, width=width)
            compile_1, step_1, _ = report.compile_and_time(_rgbd(cam), batch)
            _, _, compiled_2 = report.compile_and_time(_sharded(_rgbd(cam), mesh), placed, repeats=1)
            two_device.append(compiled_2)
            ref = native.get(f"{height}x{width}", {}) if "error" not in native else {}
            task_rows.append(
                {
                    "task": task,
                    "res": f"{height}x{width}",
                    "pixels": height * width,
                    "one": TASK_BATCH / step_1,
                    "compile": compile_1,
                    "mujoco_rgb": ref.get("rgb"),
                    "mujoco_depth": ref.get("depth"),
                }
            )
        # the resolutions' two-device programs in turns, so that load changes hit both alike
        times = report.interleaved_times(two_device, [(placed,)] * len(two_device), rounds=TASK_ROUNDS)
        for i, row in enumerate(task_rows):
            row["two"] = TASK_BATCH / statistics.median(t[i] for t in times)
        small, large = task_rows[0]["pixels"], task_rows[-1]["pixels"]
        ratios = sorted(t[0] * large / (t[-1] * small) for t in times)  # pixels/s, large / small
        task_rows[-1].update(px_ratio=statistics.median(ratios), px_ratio_min=ratios[0], px_ratio_max=ratios[-1])
        for row in task_rows:
            print(row, flush=True)
        rows += task_rows
    return rows


def _distraction(args) -> None:
    """Undistracted vs distracted 240x320 camera on each task, one device, same run."""
    from iap_mjx import envs
    from iap_mjx.configs import distraction as dcs
    from iap_mjx.envs import backgrounds
    from iap_mjx.envs.pixels import with_pixels

    tasks = [t for t in DISTRACTION_TASKS if t in envs.names()]
    videos = backgrounds.load("medium")
    config = dcs.DistractionConfig(difficulty="medium", dynamic=False)
    rows = []
    for task in tasks:
        domain, name = task.split("-")
        _, batch, _ = _states(domain, name, args.batch, args.seed)
        env = envs.make(task, obs_mode="pixels", height=240, width=320)
        distracted = with_pixels(env.env, height=240, width=320, distraction=config, videos=videos)
        keys = jax.random.split(jax.random.PRNGKey(args.seed), args.batch)
        perturbations = jax.jit(jax.vmap(distracted.distraction.reset))(keys, batch)
        plain = jax.vmap(lambda data: env.camera.render(data)[0])
        perturbed = jax.vmap(lambda data, p: distracted.render(data, p))
        compile_plain, _, plain_fn = report.compile_and_time(plain, batch, repeats=1)
        compile_dcs, _, dcs_fn = report.compile_and_time(perturbed, batch, perturbations, repeats=1)
        times = report.interleaved_times([plain_fn, dcs_fn], [(batch,), (batch, perturbations)], rounds=args.rounds)
        ratios = sorted(plain_t / dcs_t for plain_t, dcs_t in times)
        row = {
            "task": task,
            "plain": args.batch / statistics.median(t[0] for t in times),
            "dcs": args.batch / statistics.median(t[1] for t in times),
            "ratio": statistics.median(ratios),
            "ratio_min": ratios[0],
            "ratio_max": ratios[-1],
            "compile_plain": compile_plain,
            "compile_dcs": compile_dcs,
        }
        rows.append(row)
        print(row, flush=True)
    lines = [
        "Distracting Control Suite: the 240x320 RGB camera (`Camera.render`, camera 0) with all three "
        "distractions on (static, medium: perturbed pose, material colours, a 256x256 background frame "
        "as the skybox, the floor's alpha) against the same camera undistracted, frames/s on one XLA "
        f"CPU device, B = {args.batch} dm_control states per call, steady state (compile apart). "
        f"The two programs are timed in turns, {args.rounds} rounds of >= 0.3 s each, so that the "
        "machine's load changes hit both alike; the ratio is taken per round (median, and the "
        "lowest and highest round). Bar: distracted >= 90% of undistracted.",
        f"Machine: {report.machine_line()}.",
        "",
        "| task | undistracted frames/s | distracted frames/s | distracted / undistracted, median "
        "| lowest, highest round | compile undistracted (s) | compile distracted (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['task']} | {_fmt(row['plain'])} | {_fmt(row['dcs'])} | "
            f"{row['ratio']:.1%} | {row['ratio_min']:.1%}, {row['ratio_max']:.1%} | "
            f"{row['compile_plain']:.1f} | {row['compile_dcs']:.1f} |"
        )
    lines += ["", "Reproduce: `python benchmarks/camera.py --distraction`."]
    report.write_section(args.out, DISTRACTION_SECTION, "\n".join(lines))


def _fmt(value, digits=0):
    return "—" if value is None else f"{value:,.{digits}f}"


def _write(args, rows, native, per_task) -> None:
    lines = [
        f"Camera: `iap_mjx.render.Camera.render` on {args.task} (camera 0), RGB-D frames/s, "
        "steady state; states from dm_control's initial distribution plus random actions.",
        f"Machine: {report.machine_line()}.",
        "",
        "| resolution | B | ours, 1 device | ours, 2 devices | compile (s) "
        "| vmapped `mjx.ray` (depth+geom only), 1 device | ours / `mjx.ray` | MuJoCo RGB "
        "| MuJoCo depth | ours (best of 1, 2 devices) / MuJoCo RGB |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        ref = native.get(row["res"], {}) if "error" not in native else {}
        best = row.get("two", row["one"])
        ratio_ray = row["one"] / row["mjx_ray"] if row.get("mjx_ray") else None
        ratio_native = best / ref["rgb"] if ref.get("rgb") else None
        lines.append(
            f"| {row['res']} | {row['B']} | {_fmt(row['one'])} | {_fmt(row.get('two'))} | "
            f"{row['compile']:.1f} | {_fmt(row.get('mjx_ray'))} | {_fmt(ratio_ray, 1)} | "
            f"{_fmt(ref.get('rgb'))} | {_fmt(ref.get('depth'))} | {_fmt(ratio_native, 1)} |"
        )
    if "error" in native:
        lines += ["", f"MuJoCo renderer unavailable: `{native['error'].strip().splitlines()[-1]}`"]
    lines += [
        "",
        f"Per task, B = {TASK_BATCH}: RGB-D frames/s, and megapixels/s (frames/s x pixels per frame) "
        "on two devices. The two resolutions' two-device programs are timed in turns "
        f"({TASK_ROUNDS} rounds of >= 0.3 s each; their frames/s are the medians); "
        "'240x320 / 100x100' is the ratio of their pixels/s taken per round: the median, and the "
        "lowest and highest round.",
        "",
        "| task | resolution | ours, 1 device | ours, 2 devices | Mpx/s, 2 devices "
        "| 240x320 / 100x100 px/s (lowest, highest) | compile (s) | MuJoCo RGB | MuJoCo depth "
        "| ours (2 devices) / MuJoCo RGB |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in per_task:
        mpx = row["two"] * row["pixels"] / 1e6
        per_px = (
            f"{row['px_ratio']:.2f} ({row['px_ratio_min']:.2f}, {row['px_ratio_max']:.2f})"
            if "px_ratio" in row
            else "—"
        )
        ratio = row["two"] / row["mujoco_rgb"] if row.get("mujoco_rgb") else None
        lines.append(
            f"| {row['task']} | {row['res']} | {_fmt(row['one'])} | {_fmt(row['two'])} | {mpx:.1f} | "
            f"{per_px} | {row['compile']:.1f} | {_fmt(row.get('mujoco_rgb'))} | "
            f"{_fmt(row.get('mujoco_depth'))} | {_fmt(ratio, 1)} |"
        )
    lines += [
        "",
        "MuJoCo's renderer: `mujoco.Renderer` with `MUJOCO_GL=osmesa` (software GL), one process,",
        "one frame per call including `mj_forward` and `update_scene`; its frames/s do not depend",
        "on B. `mjx.ray` casts one ray per call (no cylinders), vmapped over pixels and states",
        "(timed at B in " + ", ".join(str(b) for b in args.mjx_ray_batches) + ").",
        "",
        f"Reproduce: `python benchmarks/camera.py` (`--task {args.task}`).",
    ]
    report.write_section(args.out, SECTION, "\n".join(lines))


if __name__ == "__main__":
    main()
