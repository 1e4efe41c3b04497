"""Checks that a change of code changes no compiled program: hashes of lowered programs and of
the attention layer's outputs, before and after.

What is hashed (SHA-256, one JSON entry each):

- ``lowered/attention/<kernel>/<size>``: the StableHLO text of the attention layer
  (``jax.jit(jax.vmap(layer))`` over a batch of 8 images, per-image parameters and projections,
  as the rollout batches it) for the brute, ReLU and hybrid (10,5) kernels at 100x100 with 4x4
  patches and at 240x320 with 2x2 patches; lowered only, never compiled or run.
- ``lowered/training/<preset>``: the whole ES training call of ``cheetah-run-pixels`` and
  ``dcs-cartpole-swingup`` (``make_train_call`` of ``iap_mjx.es.iteration``, or of
  ``iap_mjx.es.train`` in a base commit from before its split, lowered as ``train`` lowers it,
  on the devices the CLI makes: one per core); ``--presets`` names others.
- ``lowered/camera/<task>/<case>``: ``iap_mjx.render.Camera`` programs, ``jax.jit(jax.vmap(...))``
  over a batch of 8 states (``-single``: one state, no ``vmap``): ``render``, ``render_ids`` and
  ``trace`` on cheetah-run (whose capsules are culled per tile) at 100x100 and 240x320 (and at
  64x64 with a pair budget its states overflow, so its outputs come from the dense fallback), and
  cartpole-swingup with each input and setting the distraction layer or a config can choose (a
  background image, per-geom colours, a skybox frame shared or one per image, a frame stack
  and row, flat shading, a flat sky colour).
- ``compiled/...`` (with ``--compiled``): the same programs compiled, XLA's optimised HLO text
  without debug information (each instruction's ``metadata={...}`` and the module's tables of
  source files, Python function names and stack frames).
- ``outputs/<case>``: the bytes of the layer's ``Selection.indices`` and ``Selection.scores`` on
  fixed random images, for every kernel and the projection paths (non-overlapping and
  overlapping patches, biases, each input scaling): equal hashes mean bit-identical outputs.
- ``outputs/camera/<task>/<case>``: the bytes of the camera's rgb, depth and geom ids on fixed
  states, for the ``camera`` part's cases.

The lowered text is taken without debug information (``Lowered.as_text(debug_info=False)``: no
``loc(...)`` source locations); any ``loc(...)`` left is removed before hashing. Names of private
functions in it come from Python function names (``func.func private @_where``), so a rename
of such a function changes the lowered hash alone: ``--compiled`` and ``outputs/`` then decide.
Each program is lowered on a cleared trace cache, so its hash does not depend on which other
parts or presets the invocation names.

    python benchmarks/hlo_identity.py --out after.json                 # this checkout's hashes
    python benchmarks/hlo_identity.py --against before.json            # compare with a record
    python benchmarks/hlo_identity.py --base 2a54c1a [--compiled]      # the base commit's iap_mjx
        # (extracted with git archive into a temporary directory, run in a child process) against
        # this checkout's, entry by entry; exit status 1 if any entry differs
    python benchmarks/hlo_identity.py --only attention|camera|training|outputs ...   # a subset
    python benchmarks/hlo_identity.py --only training --presets quadruped-flat-pmtg cheetah-run-state --base 2a54c1a

Hashes depend on the jax/jaxlib version (pinned in ``constraints.txt``); compiled hashes and
output bytes also on the CPU and ``XLA_FLAGS``: compare runs on one machine.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import importlib.util
import json
import os
import re
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
EXPECTED_ROOT_VAR = "HLO_IDENTITY_EXPECTED_ROOT"
PARTS = ("attention", "camera", "training", "outputs")
PRESETS = ("cheetah-run-pixels", "dcs-cartpole-swingup")
ATTENTION_SIZES = (("100x100-p4", (100, 100, 3), 4), ("240x320-p2", (240, 320, 3), 2))
ATTENTION_KERNELS = ("brute", "relu", "hybrid")
BATCH = 8

# (case name, image shape, AttentionConfig options, batch) for the output bytes.
OUTPUT_CASES = (
    [
        (f"{kernel}/100x100-p4", (100, 100, 3), {"kernel": kernel, "patch_size": 4}, 4)
        for kernel in ("brute", "relu", "exp", "trig", "hybrid", "angular")
    ]
    + [
        ("brute-row-normalize/100x100-p4", (100, 100, 3), {"kernel": "brute", "row_normalize": True}, 4),
        ("relu/240x320-p2", (240, 320, 3), {"kernel": "relu", "patch_size": 2}, 2),
        ("hybrid/240x320-p2", (240, 320, 3), {"kernel": "hybrid", "patch_size": 2}, 2),
        ("brute/48x64-p2", (48, 64, 3), {"kernel": "brute", "patch_size": 2}, 3),
    ]
    + [
        (
            f"{kernel}/20x20-p4-stride2-{scaling}{'-bias' if bias else ''}",
            (20, 20, 3),
            {
                "kernel": kernel,
                "patch_size": 4,
                "stride": 2,
                "scaling": scaling,
                "use_bias": bias,
                "eq5_scale": 1.3,
                "top_l": 5,
                "m": 6,
                "r": 3,
            },
            3,
        )
        for kernel in ("brute", "relu", "exp", "hybrid")
        for scaling, bias in (("eq4", False), ("eq5", True), ("none", True))
    ]
    + [
        (
            f"{kernel}/20x20-p4-{scaling}-bias",
            (20, 20, 3),
            {
                "kernel": kernel,
                "patch_size": 4,
                "scaling": scaling,
                "use_bias": True,
                "eq5_scale": 1.3,
                "top_l": 5,
                "m": 6,
                "r": 3,
            },
            3,
        )
        for kernel in ("brute", "relu", "trig", "hybrid", "angular")
        for scaling in ("eq4", "eq5")
    ]
)


def sha256(data: bytes | str) -> str:
    return hashlib.sha256(data.encode() if isinstance(data, str) else data).hexdigest()


def lowered_text(lowered) -> str:
    """StableHLO text without source locations."""
    text = lowered.as_text(debug_info=False)
    return re.sub(r"\s*loc\((?:[^()]|\([^()]*\))*\)", "", text)


DEBUG_TABLES = ("FileNames", "FunctionNames", "FileLocations", "StackFrames")


def compiled_text(lowered) -> str:
    """XLA's optimised HLO without debug information: the instructions' ``metadata={...}``
    (op names, source lines) and the module's tables of source files, Python function names,
    locations and stack frames (each a header line, its rows, a blank line)."""
    kept, in_table = [], False
    for line in lowered.compile().as_text().splitlines():
        if line.strip() in DEBUG_TABLES:
            in_table = True
        elif in_table and not line.strip():
            in_table = False
        elif not in_table:
            kept.append(line)
    return re.sub(r",?\s*metadata=\{[^}]*\}", "", "\n".join(kept))


def attention_programs():
    """``(name, Lowered)`` of the layer, vmapped over a batch, per kernel and size."""
    import jax

    from iap_mjx.attention import AttentionConfig, IAPAttention

    for size, shape, patch in ATTENTION_SIZES:
        for kernel in ATTENTION_KERNELS:
            layer = IAPAttention(AttentionConfig(kernel=kernel, patch_size=patch, top_l=10, m=10, r=5), shape)
            keys = jax.random.split(jax.random.PRNGKey(0), BATCH)
            params = jax.eval_shape(jax.vmap(layer.init), keys)
            projections = jax.eval_shape(jax.vmap(layer.draw_projections), keys)
            images = jax.ShapeDtypeStruct((BATCH,) + shape, "float32")

            def attention_layer(params, projections, images, layer=layer):
                return jax.vmap(layer)(params, projections, images)

            yield f"attention/{kernel}/{size}", jax.jit(attention_layer).lower(params, projections, images)


CAMERA_STATES = 8  # batch of the vmapped camera programs and of their outputs


def _camera_states(model, count: int):
    """``count`` ``mjx.Data`` (stacked) at fixed random joint positions after ``mj_forward``."""
    import jax
    import mujoco
    import numpy as np
    from mujoco import mjx

    rng = np.random.default_rng(0)
    states = []
    for _ in range(count):
        data = mujoco.MjData(model)
        data.qpos[:] = model.qpos0 + rng.uniform(-0.3, 0.3, model.nq)
        mujoco.mj_forward(model, data)
        states.append(mjx.put_data(model, data))
    return jax.tree.map(lambda *x: np.stack(x), *states)


def camera_cases():
    """``(name, function of a stacked batch of states -> outputs, states)`` per camera case:
    each function vmaps the camera over the batch, or (``-single``) renders the first state."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from iap_mjx import envs
    from iap_mjx.render import Camera, sky

    cheetah = envs.make("cheetah-run").mj_model
    cartpole = envs.make("cartpole-swingup").mj_model
    cheetah_states = _camera_states(cheetah, CAMERA_STATES)
    cartpole_states = _camera_states(cartpole, CAMERA_STATES)
    rng = np.random.default_rng(1)
    small = Camera(cheetah, height=100, width=100)
    large = Camera(cheetah, height=240, width=320)
    yield "cheetah-run/100x100-render", jax.vmap(small.render), cheetah_states
    yield "cheetah-run/100x100-render_ids", jax.vmap(small.render_ids), cheetah_states
    yield "cheetah-run/100x100-trace", jax.vmap(small.trace), cheetah_states
    yield "cheetah-run/100x100-render-single", lambda d: small.render(jax.tree.map(lambda x: x[0], d)), cheetah_states
    yield "cheetah-run/240x320-render", jax.vmap(large.render), cheetah_states
    # a pair budget these states overflow: the dense fallback
    overflowing = Camera(cheetah, height=64, width=64, cull_pairs_per_tile=0.05, tile=8)
    yield "cheetah-run/64x64-overflow-render", jax.vmap(overflowing.render), cheetah_states

    camera = Camera(cartpole, height=64, width=80)
    background = jnp.asarray(rng.uniform(size=(64, 80, 3)), jnp.float32)
    geom_rgb = jnp.asarray(rng.uniform(size=(len(camera.geom_ids), 3)), jnp.float32)
    face = jnp.asarray(rng.integers(0, 256, (16, 16, 3)), jnp.uint8)
    stack = sky.pack_rgb(jnp.asarray(rng.integers(0, 256, (5, 16, 16, 3)), jnp.uint8))
    rows = jnp.arange(CAMERA_STATES, dtype=jnp.int32) % 5
    yield "cartpole-swingup/64x80-render", jax.vmap(camera.render), cartpole_states
    yield (
        "cartpole-swingup/64x80-background-geom_rgb",
        jax.vmap(lambda d: camera.render(d, background=background, geom_rgb=geom_rgb)),
        cartpole_states,
    )
    yield ("cartpole-swingup/64x80-sky-face", jax.vmap(lambda d: camera.render(d, sky_texture=face)), cartpole_states)
    yield (
        "cartpole-swingup/64x80-sky-stack-row-geom_rgb",
        jax.vmap(lambda d, row: camera.render(d, geom_rgb=geom_rgb, sky_texture=(stack, row))),
        (cartpole_states, rows),
    )
    yield (
        "cartpole-swingup/64x80-sky-face-per-image",
        jax.vmap(lambda d, f: camera.render(d, sky_texture=f)),
        (cartpole_states, jnp.broadcast_to(sky.pack_rgb(face), (CAMERA_STATES, 16 * 16))),
    )
    flat = Camera(cartpole, height=64, width=80, shading="flat", sky="color", background_color=(0.2, 0.3, 0.4))
    yield "cartpole-swingup/64x80-flat-color", jax.vmap(flat.render_ids), cartpole_states


def camera_programs():
    """``(name, Lowered)`` of each camera case, jitted over its batch of states."""
    import jax

    for name, fn, args in camera_cases():
        args = args if isinstance(args, tuple) else (args,)
        shapes = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), args)
        yield f"camera/{name}", jax.jit(fn).lower(*shapes)


def camera_output_hashes() -> dict[str, str]:
    """SHA-256 of each camera case's output bytes (rgb, depth, ids) on its fixed states."""
    import jax
    import numpy as np

    hashes = {}
    for name, fn, args in camera_cases():
        args = args if isinstance(args, tuple) else (args,)
        for i, value in enumerate(jax.tree.leaves(jax.jit(fn)(*args))):
            value = np.asarray(value)
            hashes[f"outputs/camera/{name}/{i}"] = sha256(value.tobytes() + str(value.dtype).encode())
    return hashes


def training_functions():
    """``(build, init_state, make_train_call)`` of the ``iap_mjx`` imported: in
    ``iap_mjx.es.components`` and ``iap_mjx.es.iteration``, or, in a base commit from before
    ``iap_mjx/es/train.py`` was split (issue 27), in that module."""
    if importlib.util.find_spec("iap_mjx.es.components") is None:
        train = importlib.import_module("iap_mjx.es.train")  # the module (``iap_mjx.es.train`` is also a function)
        return train.build, train.init_state, train.make_train_call
    components = importlib.import_module("iap_mjx.es.components")
    iteration = importlib.import_module("iap_mjx.es.iteration")
    return components.build, components.init_state, iteration.make_train_call


def training_programs(presets=PRESETS):
    """``(name, Lowered)`` of each preset's training call, lowered as ``train`` lowers it."""
    import jax
    from jax.sharding import NamedSharding, PartitionSpec

    from iap_mjx import configs

    build, init_state, make_train_call = training_functions()
    for preset in presets:
        config = configs.get(preset)
        parts = build(config)
        state = init_state(parts)
        call = make_train_call(parts, config.run.iterations_per_call)
        replicated = NamedSharding(parts.mesh, PartitionSpec())
        yield f"training/{preset}", jax.jit(call, out_shardings=replicated).lower(state)


def output_hashes() -> dict[str, str]:
    """SHA-256 of the layer's indices and scores bytes on fixed random images, per case."""
    import jax
    import numpy as np

    from iap_mjx.attention import AttentionConfig, IAPAttention

    hashes = {}
    for name, shape, options, batch in OUTPUT_CASES:
        options = {"top_l": 10, "m": 10, "r": 5, **options}
        layer = IAPAttention(AttentionConfig(**options), shape)
        keys = jax.random.split(jax.random.PRNGKey(1), batch)
        params = jax.vmap(layer.init)(keys)
        if options.get("use_bias"):
            params = params.replace(
                b_q=0.1 * jax.random.normal(jax.random.PRNGKey(2), params.b_q.shape),
                b_k=0.1 * jax.random.normal(jax.random.PRNGKey(3), params.b_k.shape),
            )
        projections = jax.vmap(layer.draw_projections)(jax.random.split(jax.random.PRNGKey(4), batch))
        images = jax.random.uniform(jax.random.PRNGKey(5), (batch,) + shape)
        selection = jax.jit(jax.vmap(layer))(params, projections, images)
        for field in ("indices", "scores"):
            value = np.asarray(getattr(selection, field))
            hashes[f"outputs/{name}/{field}"] = sha256(value.tobytes() + str(value.dtype).encode())
    return hashes


def collect(parts: tuple[str, ...], compiled: bool, presets: tuple[str, ...] = PRESETS) -> dict[str, str]:
    """Every hash of ``parts``, as ``{entry: sha256}``.

    Each program is lowered after ``jax.clear_caches()``: a program traced earlier in the
    process leaves its jaxprs in the trace cache, and a later program that reuses them shares
    their private functions, which changes its text. With the cache cleared, an entry's hash does
    not depend on which parts and presets were named before it."""
    import jax

    import iap_mjx

    expected_root = os.environ.get(EXPECTED_ROOT_VAR)
    if expected_root and not Path(iap_mjx.__file__).resolve().is_relative_to(Path(expected_root).resolve()):
        raise RuntimeError(f"iap_mjx imported from {iap_mjx.__file__}, not from {expected_root}")
    hashes = {}
    for part, programs in (
        ("attention", attention_programs),
        ("camera", camera_programs),
        ("training", lambda: training_programs(presets)),
    ):
        if part not in parts:
            continue
        jax.clear_caches()
        for name, lowered in programs():  # each lowered when the loop asks for it
            hashes[f"lowered/{name}"] = sha256(lowered_text(lowered))
            if compiled:
                hashes[f"compiled/{name}"] = sha256(compiled_text(lowered))
            print(f"  hashed {name}", file=sys.stderr, flush=True)
            jax.clear_caches()  # before the next program is traced
    if "camera" in parts:
        hashes.update(camera_output_hashes())
    if "outputs" in parts:
        hashes.update(output_hashes())
    return hashes


def run_base(commit: str, args: argparse.Namespace) -> dict[str, str]:
    """The hashes of ``commit``'s ``iap_mjx`` (this script run in a child process on it)."""
    with tempfile.TemporaryDirectory(prefix="hlo-identity-") as tmp:
        archive = subprocess.run(
            ["git", "-C", str(REPO), "archive", commit, "iap_mjx"], check=True, capture_output=True
        ).stdout
        archive_path = Path(tmp) / "base.tar"
        archive_path.write_bytes(archive)
        with tarfile.open(archive_path) as tar:
            tar.extractall(tmp, filter="data")
        out = Path(tmp) / "base.json"
        command = [sys.executable, __file__, "--out", str(out), "--only", *args.only, "--presets", *args.presets]
        if args.compiled:
            command.append("--compiled")
        env = {**os.environ, "PYTHONPATH": tmp + os.pathsep + os.environ.get("PYTHONPATH", ""), EXPECTED_ROOT_VAR: tmp}
        print(f"hashing {commit}'s iap_mjx ...", file=sys.stderr, flush=True)
        subprocess.run(command, check=True, env=env, cwd=tmp, stdout=subprocess.DEVNULL)
        return json.loads(out.read_text())["hashes"]


def compare(before: dict[str, str], after: dict[str, str]) -> bool:
    """Prints one line per entry; True if every entry present in both is equal."""
    same = True
    for name in sorted(set(before) | set(after)):
        if name not in before or name not in after:
            print(f"only {'after' if name in after else 'before'}  {name}")
            continue
        equal = before[name] == after[name]
        same &= equal
        print(f"{'same     ' if equal else 'DIFFERENT'}  {name}  {after[name][:16]}")
    return same


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, help="write this checkout's hashes here (JSON)")
    parser.add_argument("--against", type=Path, help="compare with a JSON written by --out")
    parser.add_argument("--base", help="compare with this commit's iap_mjx (run in a child process)")
    parser.add_argument("--compiled", action="store_true", help="also hash the compiled (optimised) HLO")
    parser.add_argument("--only", nargs="+", choices=PARTS, default=list(PARTS))
    parser.add_argument("--presets", nargs="+", default=list(PRESETS), help="presets whose training call is hashed")
    args = parser.parse_args(argv)
    args.only = tuple(args.only)

    from iap_mjx import runtime

    runtime.hoist_large_constants()  # as the CLI: the backgrounds are arguments of the programs
    runtime.set_host_device_count()

    before = run_base(args.base, args) if args.base else None
    if args.against:
        before = json.loads(args.against.read_text())["hashes"]
    import jax

    after = collect(args.only, args.compiled, tuple(args.presets))
    if args.out:
        args.out.write_text(
            json.dumps(
                {"jax": jax.__version__, "devices": jax.device_count(), "hashes": after}, indent=1, sort_keys=True
            )
            + "\n"
        )
    if before is None:
        for name, digest in sorted(after.items()):
            print(f"{digest[:16]}  {name}")
        return 0
    same = compare(before, after)
    print("every entry the same" if same else "SOME ENTRIES DIFFER")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
