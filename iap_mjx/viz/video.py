"""Videos and strips of an episode, written to files: what a pixel agent sees, with the selected
patches outlined in red, or, for a state agent, the env's own camera.

The episode runs compiled (:mod:`iap_mjx.viz.recording`), the host draws its steps
(:mod:`iap_mjx.viz.drawing`), and this module writes them: an MP4 (H.264 through PyAV, in this
process: nothing is forked) or a GIF of the whole episode, or a PNG strip of a few of its
frames. An env with a scene (the quadruped's courses) is shown from its scene camera with the
robot's view inset in the top-right corner.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import numpy as np

from iap_mjx.checks import require_int
from iap_mjx.viz import drawing, recording

if TYPE_CHECKING:  # viz is handed envs and policies built: it imports neither package at load
    from iap_mjx.envs.base import Env
    from iap_mjx.policies.base import Policy

logger = logging.getLogger(__name__)

STRIP_SCENE_SCALE = 6  # a strip's inset view: the course's 24x32 camera at 144x192, its caption legible


VIDEO_SUFFIXES = (".mp4", ".gif")
STRIP_SUFFIXES = (".png", ".jpg", ".jpeg")


def check_suffix(path: str | Path, suffixes: tuple[str, ...], what: str) -> None:
    """``ValueError`` unless ``path`` ends with one of ``suffixes``: checked before an episode
    runs, so a name the writer cannot take fails at once, not after the episode compiles."""
    if Path(path).suffix.lower() not in suffixes:
        raise ValueError(f"{what} {str(path)!r}: the file name must end with {' or '.join(suffixes)}")


def write_video(path: str | Path, frames: Iterable[np.ndarray], *, fps: int = 30) -> Path:
    """Writes ``frames`` (``(H, W, 3)`` uint8 each, all one size) as MP4 (``.mp4``) or GIF
    (``.gif``) and returns the path.

    MP4s are encoded in-process by PyAV's bundled FFmpeg libraries (no ``ffmpeg`` subprocess:
    forking a process that runs JAX's threads can deadlock), one frame at a time as they come
    (a 1000-step scene video is never held whole); frames are padded to even sizes, which
    H.264's 4:2:0 chroma needs. A GIF's frames are gathered first (Pillow writes them at once).
    """
    import imageio.v3 as iio

    check_suffix(path, VIDEO_SUFFIXES, "video")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    count = 0
    if path.suffix.lower() == ".mp4":
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
    env: Env,
    policy: Policy,
    params: Any,
    path: str | Path,
    *,
    key: jax.Array,
    steps: int,
    obs_stats: Any = None,
    program: Any = None,
    fps: int | None = None,
) -> tuple[Path, float]:
    """Runs one episode (:func:`~iap_mjx.viz.recording.record_episode`) and writes its annotated
    video up to the step that ends it (a fall ends a quadruped's early): a pixel env's
    observations at 3x, or, for one with a scene (:func:`~iap_mjx.viz.recording.has_scene`), the
    scene at ``recording.SCENE_VIDEO_SIZE`` with the observation inset at 4x
    (:func:`~iap_mjx.viz.drawing.draw_steps`); a state env's camera. Returns ``(path, episode
    return)``, the return counting the live steps only, as training does."""
    check_suffix(path, VIDEO_SUFFIXES, "video")
    record = recording.record_episode(env, policy, params, key, steps=steps, obs_stats=obs_stats, program=program)
    returns = recording.live_returns(record)
    scene, views = "scene" in record, "frames" in record
    frames = drawing.draw_steps(
        env,
        policy,
        record,
        np.arange(recording.last_live_step(record) + 1),
        scale=4 if scene else 3,
        numbered=False,
        scene_size=recording.SCENE_VIDEO_SIZE if views else recording.STATE_VIDEO_SIZE,
    )
    if fps is None:  # a robot seen from outside in real time (the quadruped's 0.02 s steps: 50 fps)
        timestep = getattr(env, "control_timestep", None) if scene else None
        repeat = getattr(getattr(env, "config", None), "action_repeat", 1)
        fps = max(1, round(1.0 / (timestep * repeat))) if timestep else 30
    return write_video(path, frames, fps=fps), float(returns[-1])


def episode_strip(
    env: Env,
    policy: Policy,
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
    scene_size: tuple[int, int] = recording.SCENE_VIDEO_SIZE,
) -> tuple[Path, float]:
    """Runs one episode (:func:`~iap_mjx.viz.recording.record_episode`) and writes ``frames`` of
    it, evenly spaced from the first step to the one that ends the episode, annotated as the
    video's (:func:`~iap_mjx.viz.drawing.annotate`, the step in the caption; an env with a
    scene: inset in it, :func:`~iap_mjx.viz.drawing.draw_steps`) and tiled ``columns`` to a row
    (:func:`~iap_mjx.viz.drawing.tile_grid`), as a PNG. ``scale``: the observation's (default 2,
    or 6 inset in a scene, where the course's 24x32 camera would otherwise be too small to
    read). Returns ``(path, episode return)``, the return counting the live steps only."""
    from PIL import Image

    require_int("frames", frames)
    require_int("columns", columns)
    check_suffix(path, STRIP_SUFFIXES, "strip")
    record = recording.record_episode(env, policy, params, key, steps=steps, obs_stats=obs_stats, program=program)
    returns = recording.live_returns(record)
    picks = np.unique(np.linspace(0, recording.last_live_step(record), frames).round().astype(int))
    if scale is None:
        scale = STRIP_SCENE_SCALE if "scene" in record else 2
    tiles = list(drawing.draw_steps(env, policy, record, picks, scale=scale, numbered=True, scene_size=scene_size))
    image = drawing.tile_grid(tiles, columns)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(path)
    logger.info("wrote %s (%d frames)", path, len(picks))
    return path, float(returns[-1])
