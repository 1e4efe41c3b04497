"""Our ray-cast camera next to MuJoCo's own renderer (``mujoco.Renderer``), for eyes and tests.

MuJoCo's renderer needs an OpenGL context; on a headless machine that is software OSMesa
(``apt-get install -y libosmesa6``) or EGL, chosen by ``MUJOCO_GL`` *before* ``mujoco`` is
imported. So the reference frames are rendered in a child process started with
``MUJOCO_GL=osmesa`` (``reference_frames``), which works whatever this process imported.

Command line (writes one PNG: per task, ours on top, MuJoCo's below)::

    python -m iap_mjx.viz.render_compare --out render_compare.png [--size 100] [--seed 0]
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from iap_mjx.configs import distraction

logger = logging.getLogger(__name__)

# dm_control's (domain, task) names of the suite's six tasks.
TASKS = tuple(tuple(name.split("-")) for name in distraction.TASKS)


def _suite_model(domain: str):
    import mujoco

    module = importlib.import_module(f"dm_control.suite.{domain}")
    xml, assets = module.get_model_and_assets()
    return mujoco.MjModel.from_xml_string(xml, assets)


def _set_skybox(model, renderer, frame: np.ndarray) -> None:
    """Uploads ``frame`` ``(S, S, 3)`` uint8 as the skybox texture, as the Distracting Control
    Suite does (one square face, which MuJoCo repeats on all six)."""
    import mujoco

    sky = next(t for t in range(model.ntex) if int(model.tex_type[t]) == int(mujoco.mjtTexture.mjTEXTURE_SKYBOX))
    size = frame.shape[0]
    if size * size * 3 > model.tex_width[sky] * model.tex_height[sky] * model.tex_nchannel[sky]:
        raise ValueError(f"a {size}x{size} sky does not fit the model's skybox texture")
    model.tex_width[sky] = size
    model.tex_height[sky] = size
    adr = int(model.tex_adr[sky])
    model.tex_data[adr : adr + frame.size] = frame.reshape(-1)
    renderer._gl_context.make_current()
    mujoco.mjr_uploadTexture(model, renderer._mjr_context, sky)


def _render_reference(request: dict) -> dict:
    """In the child: MuJoCo's RGB, depth and geom segmentation of each state (after the
    request's optional distractions: ``mat_rgba`` per state, a ``sky`` texture per state, and
    ``cam_xpos``/``cam_xmat`` per state written into the data of every requested camera)."""
    import mujoco

    model = (
        mujoco.MjModel.from_xml_string(str(request["xml"]))
        if "xml" in request
        else _suite_model(str(request["domain"]))
    )
    height, width = int(request["height"]), int(request["width"])
    renderer = mujoco.Renderer(model, height, width)
    data = mujoco.MjData(model)
    out: dict[str, list[list[np.ndarray]]] = {"rgb": [], "depth": [], "segmentation": []}  # [state][camera]
    for i, (qpos, geom_pos, geom_size, site_rgba) in enumerate(
        zip(request["qpos"], request["geom_pos"], request["geom_size"], request["site_rgba"])
    ):
        model.geom_pos[:] = geom_pos
        model.geom_size[:] = geom_size
        model.site_rgba[:] = site_rgba
        if "mat_rgba" in request:
            model.mat_rgba[:] = request["mat_rgba"][i]
        if "sky" in request:
            _set_skybox(model, renderer, np.asarray(request["sky"][i], np.uint8))
        data.qpos[:] = qpos
        mujoco.mj_forward(model, data)
        for camera in request["camera_ids"]:
            if "cam_xpos" in request:
                data.cam_xpos[int(camera)] = request["cam_xpos"][i]
                data.cam_xmat[int(camera)] = request["cam_xmat"][i].reshape(-1)
        for key in out:
            out[key].append([])
        for camera in request["camera_ids"]:
            renderer.update_scene(data, camera=int(camera))
            out["rgb"][-1].append(renderer.render().copy())
            renderer.enable_depth_rendering()
            renderer.update_scene(data, camera=int(camera))
            out["depth"][-1].append(renderer.render().copy())
            renderer.disable_depth_rendering()
            renderer.enable_segmentation_rendering()
            renderer.update_scene(data, camera=int(camera))
            seg = renderer.render().copy()
            renderer.disable_segmentation_rendering()
            geom = np.where(seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), seg[..., 0], -1)
            out["segmentation"][-1].append(geom.astype(np.int32))
    renderer.close()
    return {k: np.asarray(v) for k, v in out.items()}


def reference_frames(
    domain: str, states, camera_ids, height: int, width: int, distractions: dict | None = None, xml: str | None = None
) -> dict[str, np.ndarray]:
    """MuJoCo's own frames of ``states`` (``(model, data)`` pairs of dm_control's ``domain``,
    or of the model compiled from ``xml`` if given; each model's geom positions and sizes and
    site colours are applied, as tasks edit them at reset: reacher moves its target, finger
    hides two sites) from each of ``camera_ids``.

    ``distractions`` (optional) holds per-state arrays applied as the Distracting Control
    Suite applies them before rendering: ``mat_rgba`` ``(N, nmat, 4)``, ``sky`` ``(N, S, S,
    3)`` uint8 (the skybox texture) and ``cam_xpos`` ``(N, 3)`` / ``cam_xmat`` ``(N, 3, 3)``
    (written into the data after ``mj_forward``).

    Returns ``rgb`` ``(N, C, H, W, 3)`` uint8, ``depth`` ``(N, C, H, W)`` metres and
    ``segmentation`` ``(N, C, H, W)`` geom id (-1 for none), for N states and C cameras.
    Runs in one child process with ``MUJOCO_GL`` set to ``$IAP_MJX_REFERENCE_GL`` (default
    ``osmesa``).
    """
    with tempfile.TemporaryDirectory() as tmp:
        request = Path(tmp) / "request.npz"
        result = Path(tmp) / "result.npz"
        arrays: dict[str, Any] = dict(
            domain=domain,
            geom_pos=np.stack([np.asarray(m.geom_pos) for m, _ in states]),
            geom_size=np.stack([np.asarray(m.geom_size) for m, _ in states]),
            site_rgba=np.stack([np.asarray(m.site_rgba) for m, _ in states]),
            qpos=np.stack([np.asarray(d.qpos, np.float64) for _, d in states]),
            camera_ids=np.asarray(camera_ids, np.int32),
            height=height,
            width=width,
            **({} if xml is None else {"xml": xml}),
            **{k: np.asarray(v) for k, v in (distractions or {}).items()},
        )
        np.savez(request, **arrays)
        backend = os.environ.get("IAP_MJX_REFERENCE_GL", "osmesa")  # read per call, not at import
        env = dict(os.environ, MUJOCO_GL=backend, PYOPENGL_PLATFORM=backend)
        proc = subprocess.run(
            [sys.executable, "-m", "iap_mjx.viz.render_compare", "--reference", str(request), str(result)],
            env=env,
            capture_output=True,
            text=True,
        )
        if proc.returncode != 0:
            raise RuntimeError(
                f"MuJoCo's renderer failed with MUJOCO_GL={backend}"
                f"{' (is libosmesa6 installed?)' if backend == 'osmesa' else ''}:\n{proc.stderr[-2000:]}"
            )
        with np.load(result) as out:
            return {k: out[k] for k in out.files}


def suite_states(domain: str, task: str, n_states: int, seed: int):
    """``n_states`` ``(model, data)`` pairs from dm_control's initial-state distribution, each
    after a few random actions; each model is a copy (tasks edit the model at reset)."""
    import copy

    import mujoco
    from dm_control import suite

    env = suite.load(domain, task, task_kwargs={"random": seed})
    rng = np.random.default_rng(seed)
    spec = env.action_spec()
    states = []
    for _ in range(n_states):
        env.reset()
        for _ in range(int(rng.integers(0, 30))):
            env.step(rng.uniform(spec.minimum, spec.maximum))
        model = copy.copy(env.physics.model.ptr)
        data = mujoco.MjData(model)
        data.qpos[:] = env.physics.data.qpos
        data.qvel[:] = env.physics.data.qvel
        data.mocap_pos[:] = env.physics.data.mocap_pos
        mujoco.mj_forward(model, data)
        states.append((model, data))
    return states


def side_by_side(out: Path, size: int = 100, seed: int = 0, camera_id: int = 0) -> Path:
    """Writes a PNG: for each task, our render (top) and MuJoCo's (bottom)."""
    import jax
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt
    from mujoco import mjx

    from iap_mjx.render import Camera

    fig, axes = plt.subplots(2, len(TASKS), figsize=(2.2 * len(TASKS), 4.6))
    for col, (domain, task) in enumerate(TASKS):
        ((model, data),) = suite_states(domain, task, 1, seed)
        cam = Camera(model, camera_id=camera_id, height=size, width=size)
        ours, _ = jax.jit(cam.render)(mjx.put_data(model, data))
        ref = reference_frames(domain, [(model, data)], [camera_id], size, size)
        for row, (image, who) in enumerate(((np.asarray(ours), "ours"), (ref["rgb"][0, 0], "MuJoCo"))):
            axes[row, col].imshow(image)
            axes[row, col].set_title(f"{domain} ({who})", fontsize=8)
            axes[row, col].axis("off")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("render_compare.png"))
    parser.add_argument("--size", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--camera-id", type=int, default=0)
    parser.add_argument("--reference", nargs=2, type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.reference:
        request, result = args.reference
        with np.load(request) as req:
            np.savez(result, **_render_reference({k: req[k] for k in req.files}))
        return
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    path = side_by_side(args.out, size=args.size, seed=args.seed, camera_id=args.camera_id)
    logger.info("wrote %s", path)


if __name__ == "__main__":
    main()
