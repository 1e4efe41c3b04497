"""Full pixel pipeline throughput: physics + camera + attention + controller + ES update.

Each measurement runs in its own Python process (so that its peak RSS is its own) and the
table is written when all are done:

- whole program: ``iap_mjx.es.train`` for a few iterations of each attention preset
  (population sharded over every XLA CPU device); frames/s of the steady-state iterations
  (every simulated frame: population and centre evaluation; env steps are frames x action
  repeat) and the first iteration's compile time;
- brute force at sizes where the ``L x L`` matrix is too large for the rollout: one frame of
  its attention layer measured alone, and the whole program's projected cost;
- with ``--stages``, a per-stage breakdown: the population's episodes as programs that
  include successively more stages (physics; + camera; + attention), and the whole ES
  iteration (+ controller, ES bookkeeping and centre evaluation); each stage's cost is the
  difference of consecutive programs' time per frame;
- the attention layer alone, batch ``population``, sharded over the devices, in the groups
  the rollout uses;
- the 100x100 default preset measured in the same run (when the setting is another size).

    python benchmarks/pipeline.py              # 100x100, writes the pipeline section of BENCHMARKS.md
    # the pipeline-240x320-p2 section (~10 min):
    python benchmarks/pipeline.py --height 240 --width 320 --patch 2 --population 64 --episode-length 20 --iterations 3 --stages --memory-population 256
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import report  # noqa: E402

DEFAULT = "cheetah-run-pixels"
PRESETS = [
    ("hybrid (10,5)", "cheetah-run-pixels"),
    ("ReLU", "cheetah-run-pixels-relu"),
    ("brute force", "cheetah-run-pixels-brute"),
]
BRUTE_ROLLOUT_MAX_PATCHES = 2500  # beyond, brute force's L x L matrices make a rollout take hours
STAGES = ["physics", "camera", "attention"]


def peak_rss_mb() -> float:
    """This process's peak resident set size in MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


# ---------------------------------------------------------------- workers (one process each)


def work_train(job: dict) -> dict:
    """The whole program: ``train`` for ``iterations``; steady-state frames/s (median)."""
    import importlib

    from iap_mjx import configs

    train = importlib.import_module("iap_mjx.es.train")
    config = configs.apply_overrides(configs.get(job["preset"]), job["overrides"])
    with tempfile.TemporaryDirectory() as run_dir:
        history = train.train(config, run_dir=run_dir, progress=False).history
    steady = [row["env_steps_per_s"] for row in history[1:]]  # the first iteration includes compile
    return {"compile_s": history[0]["compile_s"], "frames_per_s": statistics.median(steady)}


@dataclasses.dataclass(frozen=True)
class _Idle:
    """A stage-ladder policy: zero actions that still read ``obs`` (so it is computed), or the
    IAP policy's attention features when ``iap`` is given (no controller)."""

    action_size: int
    iap: Any = None

    def init(self, key):
        return self.iap.init(key) if self.iap is not None else {}

    def initial_state(self, key):
        return self.iap.initial_state(key) if self.iap is not None else ()

    def apply(self, params, obs, policy_state):
        import jax
        import jax.numpy as jnp

        if self.iap is None:
            used = sum(jnp.mean(x) for x in jax.tree_util.tree_leaves(obs))
        else:
            projections, _ = policy_state
            used = jnp.sum(self.iap.features(params, obs, projections)[0])
        return jnp.zeros((self.action_size,)) + 0.0 * used, policy_state


def work_stage(job: dict) -> dict:
    """One rung of the stage ladder: the population's episodes (no ES update), frames/s."""
    import jax
    import jax.numpy as jnp
    from jax.flatten_util import ravel_pytree

    from iap_mjx import configs, envs, policies
    from iap_mjx.es.rollout import make_mesh, make_rollout

    config = configs.apply_overrides(configs.get(job["preset"]), job["overrides"])
    options = dict(config.env.overrides)
    if job["stage"] == "physics":
        options = {k: v for k, v in options.items() if k not in ("obs_mode", "height", "width")}
    env = envs.make(config.env.name, **options)
    iap = (
        None
        if job["stage"] != "attention"
        else policies.make(config.policy.kind, env.observation_shape, env.action_size, **dict(config.policy.options))
    )
    policy = _Idle(env.action_size, iap)
    flat, unravel = ravel_pytree(policy.init(jax.random.PRNGKey(0)))
    if flat.shape[0] == 0:
        flat = jnp.zeros((1,))
        unravel = lambda _: {}  # noqa: E731
    n = config.es.population_size
    population = flat + 0.05 * jax.random.normal(jax.random.PRNGKey(1), (n, flat.shape[0]))
    keys = jax.random.split(jax.random.PRNGKey(2), n)
    rollout = make_rollout(env, policy, unravel, make_mesh(config.run.num_devices), config.run.chunk_size, False)
    compile_s, seconds, _ = report.compile_and_time(
        lambda f, k: rollout(f, k, None), population, keys, repeats=3, min_seconds=1.0
    )
    return {"compile_s": compile_s, "frames_per_s": n * env.episode_length / seconds}


def work_attention(job: dict) -> dict:
    """The attention layer alone on ``batch`` images, ``group`` at a time per device: ms per image."""
    import attention as attention_bench
    import jax

    from iap_mjx.attention import AttentionConfig, IAPAttention

    shape = (job["height"], job["width"], 3)
    layer = IAPAttention(AttentionConfig(**job["options"]), shape)
    batch = job["batch"]
    group = job["group"] or max(1, batch // len(jax.devices()))
    images = attention_bench.place_images(jax.random.uniform(jax.random.PRNGKey(2), (batch, *shape)))
    params = layer.init(jax.random.PRNGKey(0))
    projections = layer.draw_projections(jax.random.PRNGKey(1))
    fn = attention_bench.batched_forward(layer, batch, group)
    repeats, min_seconds = (1, 0.0) if job["options"]["kernel"] == "brute" else (3, 0.3)
    compile_s, seconds, _ = report.compile_and_time(
        fn, params, projections, images, repeats=repeats, min_seconds=min_seconds
    )
    return {"compile_s": compile_s, "ms_per_image": 1e3 * seconds / batch, "group": group}


WORKERS = {"train": work_train, "stage": work_stage, "attention": work_attention}


def worker_main(job: dict) -> None:
    from iap_mjx import runtime

    runtime.set_host_device_count()
    runtime.enable_compilation_cache()
    result = WORKERS[job["kind"]](job)
    result["peak_rss_mb"] = peak_rss_mb()
    print("RESULT " + json.dumps(result), flush=True)


def run_job(job: dict) -> dict:
    """Runs ``job`` in a fresh Python process and returns its result."""
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, __file__, "--worker", json.dumps(job)], capture_output=True, text=True)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    if proc.returncode or not lines:
        raise RuntimeError(f"job {job} failed:\n{proc.stderr[-3000:]}")
    result = {**job, **json.loads(lines[-1][len("RESULT ") :]), "wall_s": time.perf_counter() - start}
    print(json.dumps(result), flush=True)
    return result


# ---------------------------------------------------------------- the table


def fmt(value: float | None, spec: str = ",.0f") -> str:
    return "-" if value is None else format(value, spec)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--height", type=int, default=100)
    parser.add_argument("--width", type=int, default=100)
    parser.add_argument("--patch", type=int, default=4)
    parser.add_argument("--population", type=int, default=64)
    parser.add_argument("--episode-length", type=int, default=50, help="frames per episode")
    parser.add_argument("--iterations", type=int, default=3)
    parser.add_argument(
        "--action-repeat",
        type=int,
        default=0,
        help="control steps per frame (0: the preset's; 1: a frame every control step)",
    )
    parser.add_argument("--stages", action="store_true", help="also the per-stage breakdown")
    parser.add_argument(
        "--memory-population",
        type=int,
        default=0,
        help="also one whole-program run of hybrid (10,5) at this population (peak RSS)",
    )
    parser.add_argument("--output", type=Path, default=report.ROOT / "BENCHMARKS.md")
    parser.add_argument("--no-write", action="store_true")
    args = parser.parse_args()
    if args.worker:
        worker_main(json.loads(args.worker))
        return 0

    from iap_mjx import runtime

    runtime.set_host_device_count()  # as the workers do, so that machine_line() names their devices
    from iap_mjx import configs
    from iap_mjx.attention import IAPAttention

    cache_was_cold = not any(runtime.enable_compilation_cache().iterdir())
    default_size = (args.height, args.width, args.patch) == (100, 100, 4)
    size = (f"env.height={args.height}", f"env.width={args.width}", f"policy.patch_size={args.patch}")
    common = (
        f"es.population_size={args.population}",
        f"env.episode_length={args.episode_length}",
        f"run.iterations={args.iterations}",
        "run.checkpoint_every=0",
        "run.tensorboard=false",
    ) + ((f"env.action_repeat={args.action_repeat}",) if args.action_repeat else ())
    config = configs.apply_overrides(configs.get(DEFAULT), list(size + common))
    repeat = dict(config.env.overrides)["action_repeat"]
    num_patches = IAPAttention(_attention_config(config), (args.height, args.width, 3)).num_patches
    brute_fits = num_patches <= BRUTE_ROLLOUT_MAX_PATCHES
    started = time.perf_counter()

    rows = []
    for label, preset in PRESETS:
        if preset.endswith("brute") and not brute_fits:
            continue
        rows.append((label, run_job({"kind": "train", "preset": preset, "overrides": list(size + common)})))
    default_row = None if default_size else run_job({"kind": "train", "preset": DEFAULT, "overrides": list(common)})
    memory_row = (
        None
        if not args.memory_population
        else run_job(
            {
                "kind": "train",
                "preset": DEFAULT,
                "overrides": list(size + common[1:])
                + [f"es.population_size={args.memory_population}", "run.iterations=2"],
            }
        )
    )
    stage_rows = [
        run_job({"kind": "stage", "stage": stage, "preset": DEFAULT, "overrides": list(size + common)})
        for stage in (STAGES if args.stages else [])
    ]
    attention_rows = []
    kernels = [("hybrid (10,5)", {"kernel": "hybrid", "m": 10, "r": 5}), ("ReLU", {"kernel": "relu"})]
    if not brute_fits:
        kernels.append(("brute force", {"kernel": "brute", "row_normalize": True}))
    for label, options in kernels:
        brute = options["kernel"] == "brute"
        for group in [0] if brute else [0, 4]:  # 0: the device's whole share, as in the rollout
            attention_rows.append(
                (
                    label,
                    run_job(
                        {
                            "kind": "attention",
                            "height": args.height,
                            "width": args.width,
                            "batch": 1 if brute else args.population,
                            "group": group,
                            "options": {"patch_size": args.patch, "top_l": 10, "d_qk": 4, **options},
                        }
                    ),
                )
            )
    total_s = time.perf_counter() - started

    body = tables(args, repeat, num_patches, rows, default_row, memory_row, stage_rows, attention_rows)
    print(body)
    print(f"total {total_s:.0f} s")
    if args.no_write:
        return 0
    command = (
        f"python benchmarks/pipeline.py --height {args.height} --width {args.width} --patch {args.patch} "
        f"--population {args.population} --episode-length {args.episode_length} "
        f"--iterations {args.iterations}"
        + (f" --action-repeat {args.action_repeat}" if args.action_repeat else "")
        + (" --stages" if args.stages else "")
        + (f" --memory-population {args.memory_population}" if args.memory_population else "")
    )
    name = "pipeline" if default_size else f"pipeline-{args.height}x{args.width}-p{args.patch}"
    cache = (
        "The persistent compilation cache was empty at the start (cold compiles; run with "
        "`IAP_MJX_CACHE_DIR=$(mktemp -d)` to reproduce that)."
        if cache_was_cold
        else "The persistent compilation cache already held programs, so compile times are mostly "
        "cache loading; run with `IAP_MJX_CACHE_DIR=$(mktemp -d)` for cold compiles."
    )
    report.write_section(
        args.output,
        name,
        (
            f"## Full pixel pipeline at {args.height}x{args.width}, patch {args.patch} (L = {num_patches:,})\n\n"
            f"Measured on {report.machine_line()}; {total_s / 60:.0f} min in all. Command: `{command}`.\n\n"
            f"`{DEFAULT}` (cheetah-run, action repeat {repeat}, LSTM(16) controller, top 10 patches) with "
            f"`env.height={args.height} env.width={args.width} policy.patch_size={args.patch}`, population "
            f"{args.population}, {args.episode_length} frames per episode, every measurement in its own "
            "process (peak RSS is that process's). Whole program: steady-state frames/s of `train` "
            "(median over the iterations after the first, every simulated frame: population and centre "
            f"evaluation; env steps = frames x {repeat}); compile: the first iteration's. " + cache + "\n\n" + body
        ),
    )
    return 0


def _attention_config(config) -> Any:
    from iap_mjx.attention import AttentionConfig

    fields = {f.name for f in dataclasses.fields(AttentionConfig)}
    return AttentionConfig(**{k: v for k, v in dict(config.policy.options).items() if k in fields})


def tables(args, repeat, num_patches, rows, default_row, memory_row, stage_rows, attention_rows) -> str:
    pixels = args.height * args.width
    out = ["| program | frames/s | env-steps/s | Mpx/s | compile s | peak RSS MB |", "|---|---:|---:|---:|---:|---:|"]

    def line(label, row, px):
        fps = row["frames_per_s"]
        out.append(
            f"| {label} | {fmt(fps)} | {fmt(fps * repeat)} | {fmt(fps * px / 1e6, '.1f')} | "
            f"{fmt(row['compile_s'], '.1f')} | {fmt(row['peak_rss_mb'])} |"
        )

    for label, row in rows:
        line(f"{args.height}x{args.width} p{args.patch}, {label}, population {args.population}", row, pixels)
    if memory_row:
        line(
            f"{args.height}x{args.width} p{args.patch}, hybrid (10,5), population {args.memory_population}",
            memory_row,
            pixels,
        )
    if default_row:
        line(f"`{DEFAULT}` default (100x100 p4), population {args.population}", default_row, 100 * 100)
    parts = ["\n".join(out)]

    if stage_rows:
        lines = [
            "Per-stage breakdown (same run, both cores): the population's episodes as programs that "
            "include successively more stages, then the whole ES iteration (hybrid (10,5) above); "
            "a stage's cost is the difference of consecutive rows' ms per frame (negative: within noise).",
            "",
            "| program | frames/s | ms / frame | stage | stage ms / frame | share | compile s |",
            "|---|---:|---:|---|---:|---:|---:|",
        ]
        names = [
            "physics only (state env, zero actions)",
            "+ camera",
            "+ attention (top-10 features)",
            "+ LSTM controller, ES update and centre evaluation (`train`)",
        ]
        ladder = [*stage_rows, rows[0][1]]
        total_ms = 1e3 / ladder[-1]["frames_per_s"]
        previous = 0.0
        for name, stage, row in zip(names, [*STAGES, "controller + ES bookkeeping"], ladder):
            ms = 1e3 / row["frames_per_s"]
            lines.append(
                f"| {name} | {fmt(row['frames_per_s'])} | {ms:.3f} | {stage} | {ms - previous:.3f} | "
                f"{100 * (ms - previous) / total_ms:.0f}% | {fmt(row['compile_s'], '.1f')} |"
            )
            previous = ms
        parts.append("\n".join(lines))

    lines = [
        f"The attention layer alone (patch projections, scores, top-10), L = {num_patches:,}, sharded "
        "over the devices (the images placed on their devices before timing, as the rollout renders "
        "them there); each device vectorises its whole share (as the rollout does: `vmap` over "
        "a chunk of episodes, which the layer scores `batch_chunk` images at a time) or runs it 4 "
        "images at a time (`lax.map`, as `benchmarks/attention.py`):",
        "",
        "| kernel | batch | images per group | ms / image | compile s |",
        "|---|---:|---:|---:|---:|",
    ]
    for label, row in attention_rows:
        lines.append(
            f"| {label} | {row['batch']} | {row['group']} | {row['ms_per_image']:.3f} | {row['compile_s']:.1f} |"
        )
    brute = next((row for name, row in attention_rows if name == "brute force"), None)
    if brute and stage_rows:
        other_ms = 1e3 / rows[0][1]["frames_per_s"] - (
            1e3 / stage_rows[2]["frames_per_s"] - 1e3 / stage_rows[1]["frames_per_s"]
        )
        devices = 2
        projected = 1e3 / (other_ms + brute["ms_per_image"] / devices)
        lines += [
            "",
            f"Brute force is not run in the rollout here (L > {BRUTE_ROLLOUT_MAX_PATCHES:,}): its "
            f"L x L logits and their exponentials take {2 * 4 * num_patches**2 / 2**30:.1f} GiB per "
            f"image. One frame measured alone takes "
            f"{brute['ms_per_image']:,.0f} ms; with the other stages as measured above (hybrid's "
            f"attention replaced, {devices} devices in parallel) the whole program would run at about "
            f"**{projected:.1f} frames/s** (projected, not measured).",
        ]
    parts.append("\n".join(lines))
    if (args.height, args.width, args.patch) == (240, 320, 2):  # the setting issue 13's bars are for
        parts.append(bars(args, rows, default_row, attention_rows))
    return "\n\n".join(parts)


def bars(args, rows, default_row, attention_rows) -> str:
    """Issue 13's bars, read off this run's rows."""
    out = [
        f"Bars (issue 13), from this run (1-min load average at the end: {os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} cores):"
    ]

    def verdict(ok):
        return "met" if ok else "NOT met"

    by_label = dict(rows)
    pixels = args.height * args.width
    for label, bar in (("hybrid (10,5)", 400), ("ReLU", 600)):
        if label in by_label:
            fps = by_label[label]["frames_per_s"]
            out.append(
                f"- whole program, {label}, population {args.population}: {fps:,.0f} frames/s "
                f"(bar {bar}: {verdict(fps >= bar)})."
            )
    if default_row and "hybrid (10,5)" in by_label:
        here = by_label["hybrid (10,5)"]["frames_per_s"] * pixels
        base = default_row["frames_per_s"] * 100 * 100
        out.append(
            f"- per pixel vs the 100x100 default: {here / 1e6:.1f} vs {base / 1e6:.1f} Mpx/s ({verdict(here >= base)})."
        )
    for label, bar in (("hybrid (10,5)", 1.0), ("ReLU", 0.5)):
        row = min((r for name, r in attention_rows if name == label), key=lambda r: r["ms_per_image"], default=None)
        if row:
            out.append(
                f"- attention alone, {label}, batch {row['batch']} (best grouping): {row['ms_per_image']:.3f} ms/image "
                f"(bar {bar}: {verdict(row['ms_per_image'] <= bar)})."
            )
    if "hybrid (10,5)" in by_label:
        compile_s = by_label["hybrid (10,5)"]["compile_s"]
        out.append(
            f"- compile of the whole program (hybrid): {compile_s:.1f} s (bar < 60 s cold: "
            f"{verdict(compile_s < 60)}{'' if rows else ''})."
        )
    return "\n".join(out)


if __name__ == "__main__":
    raise SystemExit(main())
