"""Videos of an episode: what a pixel agent sees, with the selected patches outlined in red, or,
for a state agent, the env's own camera.

One episode runs compiled (``lax.scan``); the host then upscales each frame, outlines the
top-l patches the attention layer picked (as the paper's Figures 9-10) and writes the return
so far, and saves an MP4 (H.264 through PyAV, in this process: nothing is forked) or a GIF. A
state env has no image in its observations, so it is shown by the ray-cast camera from its
``video_camera_id`` (a model camera, e.g. the quadruped's trunk-tracking one; default camera
0) at ``STATE_VIDEO_SIZE``. A pixel env that names a ``video_camera_id`` (the quadruped's
courses, whose observation is the robot's own small camera) is shown from that camera at
``SCENE_VIDEO_SIZE``, the robot's view with its patches inset in the top-right corner. Such a
scene is not rendered inside the episode: the episode records the scene camera's poses at each
step, and the host renders the steps it draws from them, a chunk at a time.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from iap_mjx.attention.patches import patch_corner
from iap_mjx.checks import require_int

logger = logging.getLogger(__name__)

RED = (230, 30, 30)
WHITE = (255, 255, 255)
MARK_BELOW = 12  # pixels: a patch drawn smaller than this also gets a ring around it
MARK_RADIUS = 8  # pixels, the ring's outer radius
STATE_VIDEO_SIZE = (240, 320)  # (height, width) of frames rendered for state envs
SCENE_VIDEO_SIZE = (360, 480)  # (height, width) of the scene around a pixel env's inset view
INSET_MARGIN = 8  # pixels between the inset view and the frame's edges
CAPTION_HEIGHT = 16  # pixels of the black band above a frame that holds its caption
STRIP_SCENE_SCALE = 6  # a strip's inset view: the course's 24x32 camera at 144x192, its caption legible
RENDER_CHUNK = 50  # scene frames rendered per call: a bounded batch, one compiled shape


def newest_rgb(obs: Any, channels_per_frame: int) -> jax.Array:
    """The newest RGB frame ``(H, W, 3)`` of a (frame-stacked) pixel observation; a depth-only
    frame (one channel, ``"depth+state"``, in [0, 1]) is shown as grey, near dark."""
    pixels = obs["pixels"] if isinstance(obs, dict) else obs
    newest = pixels[..., pixels.shape[-1] - channels_per_frame :][..., :3]
    return jnp.repeat(newest, 3, axis=-1) if channels_per_frame == 1 else newest


def has_pixels(env: Any) -> bool:
    """Whether ``env`` observes pixels (else a video renders the env's own camera)."""
    return getattr(env, "obs_mode", "state") != "state"


def has_scene(env: Any) -> bool:
    """Whether ``env`` observes pixels and names a camera to show its scene from
    (``video_camera_id``): its videos show that scene with the observed view inset."""
    return has_pixels(env) and hasattr(env, "video_camera_id")


def state_camera(env: Any, size: tuple[int, int] = STATE_VIDEO_SIZE) -> Any:
    """The ray-cast camera a video of a state env is rendered with: the model camera
    ``env.video_camera_id`` (default 0), every geom group drawn."""
    from iap_mjx.render import Camera

    if env.mj_model.ncam == 0:
        raise ValueError(
            f"{getattr(env, 'name', env)!r} observes the state and its model has no camera to render a video from"
        )
    return Camera(env.mj_model, camera_id=int(getattr(env, "video_camera_id", 0)), height=size[0], width=size[1])


def episode_program(
    env: Any, policy: Any, *, steps: int, extra: Callable[[Any], dict] | None = None, scene: bool = True
) -> Any:
    """The jitted episode ``(params, obs_stats, key) -> record`` that :func:`record_episode` runs.

    Params, observation statistics (``None``: raw observations) and the key are arguments, not
    constants, so the program can be compiled before the params it will run exist
    (:func:`compile_episode_program`) and is compiled once for every checkpoint. The episode
    is training's own (:func:`iap_mjx.es.episode.run_episode`); what a video needs is its
    ``record`` of each step.

    Args:
      env: an env following the Env protocol: a pixel env (its newest frame is recorded; one
        with a scene, :func:`has_scene`, also records the scene camera's poses) or a state env
        (the poses of :func:`state_camera` alone). Poses (:meth:`iap_mjx.render.Camera.poses`,
        a few hundred floats a step) are drawn afterwards by :func:`render_scene`, only at the
        steps drawn, a chunk at a time.
      policy: the policy; if it has ``select`` (IAP) and the env has pixels, the selected
        patches are recorded.
      steps: control steps to record.
      extra: ``state -> {name: array}`` recorded too, from the state the policy sees (e.g.
        the geom map of its frame: ``viz.attended``).
      scene: ``False``: no scene poses for a pixel env with a scene (a program that draws
        nothing, e.g. ``viz.attended``'s).

    Returns a jitted function whose record is ``{"frames": (T, H, W, 3) float (pixel envs),
    "indices": (T, l) int or absent, "scene": {name: (T, ...)} or absent, "rewards": (T,),
    "alive": (T,)}`` (``scene``: the scene camera's poses of the state each step shows;
    ``alive``: the episode's own record of the steps its return counts,
    :func:`iap_mjx.es.episode.run_episode`) and ``extra``'s entries ``(T, ...)``.
    """
    from iap_mjx.es.episode import Step, run_episode

    channels = getattr(env, "channels", 3)
    pixels = has_pixels(env)
    selects = pixels and hasattr(policy, "select")
    # a state env's only picture is its scene; the poses do not depend on the size drawn
    scene_camera = state_camera(env) if not pixels or (scene and has_scene(env)) else None

    @jax.jit
    def program(params, obs_stats, key):
        def record(step: Step) -> dict:
            kept = dict(extra(step.state)) if extra is not None else {}
            if pixels:
                kept["frames"] = newest_rgb(step.state.obs, channels)
            if selects:
                kept["indices"] = policy.select(params, step.seen, step.policy_state).indices
            if scene_camera is not None:
                kept["scene"] = scene_camera.poses(step.state.data)
            kept["rewards"] = step.next_state.reward
            return kept

        return run_episode(env, policy, params, key, obs_stats, steps=steps, record=record).records

    return program


def compile_episode_program(env: Any, policy: Any, *, steps: int, obs_stats: Any = None) -> Any:
    """:func:`episode_program` compiled ahead of time for ``policy``'s params shapes (and
    ``obs_stats``'s, if given): pass it to :func:`record_episode` as ``program``. Safe to call
    from a background thread while something else compiles or trains."""
    params = jax.eval_shape(policy.init, jax.random.PRNGKey(0))
    stats = None if obs_stats is None else jax.eval_shape(lambda: obs_stats)
    return episode_program(env, policy, steps=steps).lower(params, stats, jax.random.PRNGKey(0)).compile()


def record_episode(
    env: Any, policy: Any, params: Any, key: jax.Array, *, steps: int, obs_stats: Any = None, program: Any = None
) -> dict[str, Any]:
    """Rolls one episode of ``steps`` control steps and records what a video needs.

    Args:
      env, policy, steps: as :func:`episode_program`.
      params: the policy's params.
      key: PRNG key for the env reset and the policy's per-episode state.
      obs_stats: the run's observation statistics (``None``: observations as they are).
      program: a compiled program from :func:`compile_episode_program` for the same env,
        policy and steps (default: compiled here).

    Returns:
      ``{"frames": (T, H, W, 3) float (pixel envs), "indices": (T, l) int or absent,
      "scene": {name: (T, ...)} or absent, "rewards": (T,), "alive": (T,) bool}``: ``alive`` marks the steps whose reward the episode's return
      counts (up to the one that ends it); the program runs all ``steps``, ended or not.
    """
    if program is None:
        program = episode_program(env, policy, steps=steps)
    record = jax.tree_util.tree_map(np.asarray, program(params, obs_stats, key))
    return {**record, "alive": record["alive"] > 0}


def last_live_step(record: dict[str, np.ndarray]) -> int:
    """The index of a recorded episode's last live step (the one that ends it, or the last)."""
    return int(np.flatnonzero(record["alive"])[-1])


def live_returns(record: dict[str, np.ndarray]) -> np.ndarray:
    """``(T,)`` the return so far at each step, counting live steps' rewards only."""
    return np.cumsum(np.where(record["alive"], record["rewards"], 0.0))


@functools.lru_cache(maxsize=4)
def _scene_renderer(camera: Any) -> Callable[[dict], jax.Array]:
    """The jitted batched render of a scene camera's poses, built once per camera (cameras are
    hashable), so that every video and strip of one env shares its compiled programs."""
    return jax.jit(jax.vmap(lambda pose: camera.render_poses(pose)[0]))


def render_scene(
    env: Any, poses: dict[str, np.ndarray], size: tuple[int, int] = SCENE_VIDEO_SIZE, *, batch: int | None = None
) -> np.ndarray:
    """``(N, H, W, 3)`` uint8: the scene camera's (:func:`state_camera`, ``size``) frames of
    ``N`` recorded steps' poses (a record's ``"scene"`` at those steps), rendered ``batch`` at a
    time (default ``min(RENDER_CHUNK, N)``), the last batch padded: one compiled shape."""
    render = _scene_renderer(state_camera(env, size))
    count = len(next(iter(poses.values())))
    batch = min(RENDER_CHUNK, count) if batch is None else batch
    frames = []
    for start in range(0, count, batch):
        chunk = {name: value[start : start + batch] for name, value in poses.items()}
        filled = len(next(iter(chunk.values())))
        padded = {
            name: np.concatenate([value, np.repeat(value[-1:], batch - filled, axis=0)])
            for name, value in chunk.items()
        }
        rgb = np.asarray(render(padded))[:filled]
        frames.append((np.clip(rgb, 0, 1) * 255).astype(np.uint8))
    return np.concatenate(frames)


def fit_inset(frame_shape: tuple[int, int], scale: int, scene_size: tuple[int, int]) -> tuple[int, tuple[int, int]]:
    """``(scale, scene size)`` that hold an observation of ``frame_shape`` ``(h, w)``, annotated
    (a ``CAPTION_HEIGHT`` caption on top), inside a scene frame with :func:`inset`'s margins: ``scale``
    lowered as far as 1 where the view would not fit ``scene_size``, and the scene enlarged
    where even that does not fit (a large first-person camera)."""
    (height, width), (scene_h, scene_w) = frame_shape, scene_size
    fits = min((scene_h - 2 * INSET_MARGIN - CAPTION_HEIGHT) // height, (scene_w - 2 * INSET_MARGIN) // width)
    scale = max(1, min(scale, fits))
    return scale, (
        max(scene_h, CAPTION_HEIGHT + height * scale + 2 * INSET_MARGIN),
        max(scene_w, width * scale + 2 * INSET_MARGIN),
    )


def inset(scene: np.ndarray, view: np.ndarray) -> np.ndarray:
    """Pastes ``view`` (an annotated observation, uint8) into ``scene``'s (uint8 ``(H, W, 3)``,
    changed in place and returned) top-right corner inside a 2-pixel white frame,
    ``INSET_MARGIN`` pixels from the edges; ``ValueError`` if it does not fit
    (:func:`fit_inset` chooses sizes that do)."""
    height, width = view.shape[:2]
    if height + 2 * INSET_MARGIN > scene.shape[0] or width + 2 * INSET_MARGIN > scene.shape[1]:
        raise ValueError(f"an inset of {view.shape[:2]} pixels does not fit a {scene.shape[:2]} frame")
    top, left = INSET_MARGIN, scene.shape[1] - INSET_MARGIN - width
    scene[top - 2 : top + height + 2, left - 2 : left + width + 2] = 255
    scene[top : top + height, left : left + width] = view
    return scene


def draw_steps(
    env: Any,
    policy: Any,
    record: dict[str, Any],
    steps: np.ndarray,
    *,
    scale: int,
    numbered: bool,
    scene_size: tuple[int, int] = SCENE_VIDEO_SIZE,
) -> Iterator[np.ndarray]:
    """Yields the drawn frames (uint8) of a record's ``steps``, each captioned (:func:`annotate`;
    ``numbered``: the step in the caption): a pixel env's observation at ``scale`` with its
    patches, inset in the scene rendered at ``scene_size`` where the record has one
    (:func:`has_scene`; :func:`fit_inset` adjusts both so that the view fits); a state env's
    scene alone at ``scene_size``. Scene frames are rendered ``RENDER_CHUNK`` at a time as
    they are drawn, so a whole episode is never held at once."""
    returns = live_returns(record)
    layer = getattr(policy, "layer", None)
    indices = record.get("indices")
    views, scene = record.get("frames"), record.get("scene")
    if views is not None and scene is not None:
        scale, scene_size = fit_inset(views.shape[1:3], scale, scene_size)
    batch = min(RENDER_CHUNK, len(steps))
    for start in range(0, len(steps), batch):
        chunk = steps[start : start + batch]
        scenes = None
        if scene is not None:
            scenes = render_scene(env, {name: value[chunk] for name, value in scene.items()}, scene_size, batch=batch)
        for i, t in enumerate(chunk):
            step = int(t) if numbered else None
            if views is None:
                yield annotate(scenes[i], None, None, float(returns[t]), scale=1, step=step)
                continue
            view = annotate(
                views[t], None if indices is None else indices[t], layer, float(returns[t]), scale=scale, step=step
            )
            yield view if scenes is None else inset(scenes[i], view)


def annotate(
    frame: np.ndarray,
    indices: np.ndarray | None,
    layer: Any,
    episode_return: float,
    *,
    scale: int = 3,
    step: int | None = None,
) -> np.ndarray:
    """``frame (H, W, 3)`` (floats in [0, 1], or uint8) -> ``(scale H + CAPTION_HEIGHT, scale W, 3)``
    uint8 with patches and text.

    Each selected patch is outlined in red, a white line just inside the red one (a red line
    alone vanishes on the quadruped course's red walls); one drawn smaller than ``MARK_BELOW``
    pixels (a 2x2 patch at 3x is 6 pixels) has no room inside and instead gets a 2-pixel red ring
    of radius ``MARK_RADIUS`` around its centre, inside a white ring, so that it can be seen at a
    glance on any background (a red ring alone vanishes on the suite's red retina photograph).
    """
    from PIL import Image, ImageDraw

    pixels = frame if frame.dtype == np.uint8 else (np.clip(frame, 0, 1) * 255).astype(np.uint8)
    image = Image.fromarray(pixels)
    image = image.resize((frame.shape[1] * scale, frame.shape[0] * scale), Image.NEAREST)
    canvas = Image.new("RGB", (image.width, image.height + CAPTION_HEIGHT), (0, 0, 0))
    canvas.paste(image, (0, CAPTION_HEIGHT))
    draw = ImageDraw.Draw(canvas)
    if indices is not None and layer is not None:
        cols, stride = layer.grid[1], layer.config.effective_stride
        corners = [patch_corner(int(index), cols, stride) for index in indices]
        boxes = [(column * scale, CAPTION_HEIGHT + row * scale) for row, column in corners]
        size = layer.config.patch_size * scale
        if size >= MARK_BELOW:  # white lines inside the red ones, all drawn first: overlapping
            for left, top in boxes:  # patches (stride < patch) keep every red edge whole
                draw.rectangle([left + 1, top + 1, left + size - 2, top + size - 2], outline=WHITE)
        for left, top in boxes:
            draw.rectangle([left, top, left + size - 1, top + size - 1], outline=RED)
            if size < MARK_BELOW:
                x, y = left + size / 2, top + size / 2
                halo = MARK_RADIUS + 2
                draw.ellipse([x - halo, y - halo, x + halo, y + halo], outline=WHITE, width=2)
                draw.ellipse([x - MARK_RADIUS, y - MARK_RADIUS, x + MARK_RADIUS, y + MARK_RADIUS], outline=RED, width=2)
    caption = f"return {episode_return:8.2f}" if step is None else f"step {step}   return {episode_return:.2f}"
    draw.text((2, 2), caption, fill=(255, 255, 255))
    return np.asarray(canvas)


def write_video(path: str | Path, frames: Iterable[np.ndarray], *, fps: int = 30) -> Path:
    """Writes ``frames`` (``(H, W, 3)`` uint8 each, all one size) as MP4 (``.mp4``) or GIF (any
    other suffix) and returns the path.

    MP4s are encoded in-process by PyAV's bundled FFmpeg libraries (no ``ffmpeg`` subprocess:
    forking a process that runs JAX's threads can deadlock), one frame at a time as they come
    (a 1000-step scene video is never held whole); frames are padded to even sizes, which
    H.264's 4:2:0 chroma needs. A GIF's frames are gathered first (Pillow writes them at once).
    """
    import imageio.v3 as iio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    count = 0
    if path.suffix == ".mp4":
        with iio.imopen(path, "w", plugin="pyav") as file:
            file.init_video_stream("libx264", fps=fps)
            for frame in frames:
                height, width = frame.shape[:2]
                file.write_frame(np.pad(frame, ((0, height % 2), (0, width % 2), (0, 0))))
                count += 1
    else:
        stack = np.stack(list(frames))
        count = len(stack)
        iio.imwrite(path, stack, plugin="pillow", duration=1000 / fps, loop=0)
    logger.info("wrote %s (%d frames)", path, count)
    return path


def episode_video(
    env: Any,
    policy: Any,
    params: Any,
    path: str | Path,
    *,
    key: jax.Array,
    steps: int,
    obs_stats: Any = None,
    program: Any = None,
    fps: int | None = None,
) -> tuple[Path, float]:
    """Runs one episode (:func:`record_episode`) and writes its annotated video up to the step
    that ends it (a fall ends a quadruped's early): a pixel env's observations at 3x, or, for
    one with a scene (:func:`has_scene`), the scene at ``SCENE_VIDEO_SIZE`` with the
    observation inset at 4x (:func:`draw_steps`); a state env's camera. Returns ``(path,
    episode return)``, the return counting the live steps only, as training does."""
    record = record_episode(env, policy, params, key, steps=steps, obs_stats=obs_stats, program=program)
    returns = live_returns(record)
    scene, views = "scene" in record, "frames" in record
    frames = draw_steps(
        env,
        policy,
        record,
        np.arange(last_live_step(record) + 1),
        scale=4 if scene else 3,
        numbered=False,
        scene_size=SCENE_VIDEO_SIZE if views else STATE_VIDEO_SIZE,
    )
    if fps is None:  # a robot seen from outside in real time (the quadruped's 0.02 s steps: 50 fps)
        timestep = getattr(env, "control_timestep", None) if scene else None
        repeat = getattr(getattr(env, "config", None), "action_repeat", 1)
        fps = max(1, round(1.0 / (timestep * repeat))) if timestep else 30
    return write_video(path, frames, fps=fps), float(returns[-1])


def episode_strip(
    env: Any,
    policy: Any,
    params: Any,
    path: str | Path,
    *,
    key: jax.Array,
    steps: int,
    frames: int = 6,
    columns: int = 3,
    obs_stats: Any = None,
    program: Any = None,
    scale: int | None = None,
    scene_size: tuple[int, int] = SCENE_VIDEO_SIZE,
) -> tuple[Path, float]:
    """Runs one episode (:func:`record_episode`) and writes ``frames`` of it, evenly spaced from
    the first step to the one that ends the episode, annotated as the video's (:func:`annotate`,
    the step in the caption; an env with a scene: inset in it, :func:`draw_steps`) and tiled
    ``columns`` to a row, as a PNG. ``scale``: the observation's (default 2, or 6 inset in a
    scene, where the course's 24x32 camera would otherwise be too small to read). Returns
    ``(path, episode return)``, the return counting the live steps only."""
    from PIL import Image

    require_int("frames", frames)
    require_int("columns", columns)
    record = record_episode(env, policy, params, key, steps=steps, obs_stats=obs_stats, program=program)
    returns = live_returns(record)
    picks = np.unique(np.linspace(0, last_live_step(record), frames).round().astype(int))
    if scale is None:
        scale = STRIP_SCENE_SCALE if "scene" in record else 2
    tiles = list(draw_steps(env, policy, record, picks, scale=scale, numbered=True, scene_size=scene_size))
    rows = [tiles[i : i + columns] for i in range(0, len(tiles), columns)]
    blank = np.zeros_like(tiles[0])
    gap = np.full((tiles[0].shape[0], 4, 3), 255, np.uint8)
    lines = [
        np.concatenate([part for tile in row + [blank] * (columns - len(row)) for part in (tile, gap)][:-1], axis=1)
        for row in rows
    ]
    rule = np.full((4, lines[0].shape[1], 3), 255, np.uint8)
    image = np.concatenate([part for line in lines for part in (line, rule)][:-1], axis=0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(path)
    logger.info("wrote %s (%d frames)", path, len(picks))
    return path, float(returns[-1])
