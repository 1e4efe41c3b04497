"""Background videos for the Distracting Control Suite: loaded once, resized to the sky texture.

The reference (google-research ``distracting_control/background.py``) replaces the skybox
texture with a frame of a DAVIS-2017 video; every frame is resized to the square texture
(``tf.image.resize``: bilinear, half-pixel centres, no antialiasing, then a truncating cast
to uint8; the aspect ratio is not kept). Here every frame is resized once, at load time, to
``size x size`` and the whole set is one array ``(videos, frames, size, size, 3)`` uint8, so
that a compiled step only indexes it (the distraction layer draws the video and frame per
episode and samples the sky by ray direction).

Which videos a level shows, and the checks of a setting that need no decoding, are the
suite's settings (``iap_mjx.configs.background_sets``: the DAVIS-2017 lists, the photographs;
``iap_mjx.configs.distraction.check_backgrounds``); this module makes their pixels. Two sources:

- ``load_davis(root, difficulty)``: a DAVIS-2017 directory, either the dataset's own layout
  ``<root>/JPEGImages/480p/<video>/<frame>.jpg`` or ``<root>/<video>/<frame>.jpg``; frames
  sorted by file name; the videos are the first ``num_videos(difficulty)`` of the reference's
  DAVIS-2017 training list (easy 4, medium 8, hard all 60).
- ``builtin_videos(difficulty)``: works on a fresh machine with nothing downloaded. Natural
  photographs that ship inside the scikit-image wheel (``skimage/data``: public domain or
  CC0, see ``background_sets.PHOTOGRAPHS`` and ``docs/backgrounds.md``), each made into a
  short "video" by a smooth, periodic pan and zoom through the photo (deterministic): ten
  videos, easy the first 4, medium the first 8, hard all 10.

Each source has two disjoint sets, named as the reference names them (its
``background_dataset_videos``): ``"train"``, what training draws from, and ``"val"``, held out
for evaluating generalisation to backgrounds never seen in training: the reference's 30
DAVIS-2017 validation videos, or ten other photographs
(``background_sets.VALIDATION_PHOTOGRAPHS``, shipped in scikit-image and matplotlib), with the
same counts per difficulty.

``load(difficulty, background_dir=None)`` picks one (``None``: the photographs);
``configs.distraction.check_backgrounds(difficulty, background_dir)`` runs the same validation
without decoding an image, cheap enough to run before any compile. Every bad setting raises
``ValueError`` naming the setting and what is valid.

Memory: ``videos * frames * size**2 * 3`` bytes (``BackgroundVideos.nbytes``). DAVIS-2017
480p training videos have up to about 100 frames, so at the default ``size=256``
(192 KiB a frame) medium (8 videos) takes up to ~160 MB and hard (60) up to ~1.2 GB;
``size=128`` a quarter of that (~40 MB / ~300 MB). The photographs at 32 frames: 50 MB
(medium) / 63 MB (hard) at 256. The reference's texture is 800 x 800; at 240 x 320 with
dm_control's 45-degree field of view one cube face spans about 580 pixels, so 256 is about
half the screen's resolution, 128 a quarter. The distraction layer closes over the frames,
so a process that builds a distracted env calls ``iap_mjx.runtime.hoist_large_constants()``
first (the CLI does): XLA then takes them as an argument instead of embedding them in the
program.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from iap_mjx.configs.background_sets import PACKAGE_DATA, Photograph
from iap_mjx.configs.distraction import (
    DEFAULT_NUM_FRAMES,
    DEFAULT_SIZE,
    check_backgrounds,
    davis_frame_paths,
    level_photographs,
)

logger = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True, eq=False)
class BackgroundVideos:
    """A set of background videos, every frame ``size x size``.

    Attributes:
      frames: ``(V, F, S, S, 3)`` uint8. ``F`` is the longest video's frame count; a shorter
        video is padded by repeating its last frame, so every index ``< F`` is one of its
        real frames, but a sampler must draw frame indices below ``lengths[v]``.
      lengths: ``(V,)`` int32, each video's true frame count (``1 <= lengths <= F``).
      names: the ``V`` video names.
      source: where they came from: ``"builtin"`` or ``"davis:<dir>"``, with ``":val"``
        appended for the held-out set (``"builtin:val"``, ``"davis:<dir>:val"``).
    """

    frames: np.ndarray
    lengths: np.ndarray
    names: tuple[str, ...]
    source: str

    def __post_init__(self):
        frames, lengths = self.frames, self.lengths
        if frames.dtype != np.uint8 or frames.ndim != 5 or frames.shape[-1] != 3 or frames.shape[2] != frames.shape[3]:
            raise ValueError(
                f"BackgroundVideos.frames must be uint8 (V, F, S, S, 3), got {frames.dtype} {frames.shape}."
            )
        if lengths.dtype != np.int32 or lengths.shape != frames.shape[:1]:
            raise ValueError(
                f"BackgroundVideos.lengths must be int32 ({frames.shape[0]},), got {lengths.dtype} {lengths.shape}."
            )
        if np.any(lengths < 1) or np.any(lengths > frames.shape[1]):
            raise ValueError(f"BackgroundVideos.lengths must be in [1, {frames.shape[1]}], got {lengths}.")
        if len(self.names) != frames.shape[0]:
            raise ValueError(f"BackgroundVideos.names must have {frames.shape[0]} names, got {len(self.names)}.")

    @property
    def num_videos(self) -> int:
        return int(self.frames.shape[0])

    @property
    def num_frames(self) -> int:
        """``F``, the padded frame count."""
        return int(self.frames.shape[1])

    @property
    def size(self) -> int:
        return int(self.frames.shape[2])

    @property
    def nbytes(self) -> int:
        return int(self.frames.nbytes)


# ---- resizing ----------------------------------------------------------------------------


def _axis_taps(in_size: int, out_size: int, start: float, extent: float):
    """Source taps of ``out_size`` samples over ``[start, start + extent)`` of an axis.

    Half-pixel centres, as TensorFlow's bilinear resize computes them in float32:
    ``x = start + (i + 0.5) * extent / out_size - 0.5``, taps ``floor(x)`` and ``ceil(x)``
    clamped to the axis, weight ``x - floor(x)``.
    """
    scale = np.float32(extent) / np.float32(out_size)
    x = np.float32(start) + (np.arange(out_size, dtype=np.float32) + np.float32(0.5)) * scale - np.float32(0.5)
    floor = np.floor(x)
    lower = np.clip(floor, 0, in_size - 1).astype(np.intp)
    upper = np.clip(np.ceil(x), 0, in_size - 1).astype(np.intp)
    return lower, upper, (x - floor).astype(np.float32)


def _sample_window(pixels: np.ndarray, top: float, left: float, height: float, width: float, size: int) -> np.ndarray:
    """``size x size`` bilinear samples of the window ``[top, top+height) x [left, left+width)``
    of ``pixels`` ``(H, W, 3)`` float32; float32 ``(size, size, 3)``.

    Interpolates across first, on the source rows the taps use only, then down: the same
    float32 operations per sample as interpolating each output pixel from its four taps, with
    each row's horizontal pass done once (``np.take`` along one axis, not a 2-D gather)."""
    rows = _axis_taps(pixels.shape[0], size, top, height)
    cols = _axis_taps(pixels.shape[1], size, left, width)
    needed, where = np.unique(np.concatenate([rows[0], rows[1]]), return_inverse=True)
    picked = np.take(pixels, needed, axis=0)
    left_values, right_values = np.take(picked, cols[0], axis=1), np.take(picked, cols[1], axis=1)
    across = left_values + (right_values - left_values) * cols[2][None, :, None]  # (len(needed), size, 3)
    top_values, bottom_values = np.take(across, where[:size], axis=0), np.take(across, where[size:], axis=0)
    return top_values + (bottom_values - top_values) * rows[2][:, None, None]


def _to_uint8(values: np.ndarray) -> np.ndarray:
    """The reference's ``tf.cast(..., tf.uint8)``: truncation toward zero."""
    return np.clip(values, 0, 255).astype(np.uint8)


def resize_frame(image: np.ndarray, size: int) -> np.ndarray:
    """The reference's frame resize: ``(H, W, 3)`` uint8 -> ``(size, size, 3)`` uint8.

    ``tf.image.resize(image, [size, size])`` (bilinear, half-pixel centres, no antialiasing;
    the aspect ratio is not kept) then a truncating cast to uint8. A frame already
    ``size x size`` is returned unchanged, as the reference does.
    """
    if image.shape[:2] == (size, size):
        return image
    return _to_uint8(_sample_window(image.astype(np.float32), 0.0, 0.0, image.shape[0], image.shape[1], size))


# ---- assembling --------------------------------------------------------------------------


def _stack(videos: Sequence[np.ndarray], names: Sequence[str], source: str) -> BackgroundVideos:
    """Pads each ``(F_v, S, S, 3)`` video to the longest by repeating its last frame."""
    lengths = np.array([len(video) for video in videos], np.int32)
    longest = int(lengths.max())
    frames = np.stack(
        [np.concatenate([video, np.repeat(video[-1:], longest - len(video), axis=0)]) for video in videos]
    )
    result = BackgroundVideos(frames=frames, lengths=lengths, names=tuple(names), source=source)
    logger.info(
        "background videos from %s: %d videos, %d frames (padded), %dx%d, %.1f MB",
        source,
        result.num_videos,
        result.num_frames,
        result.size,
        result.size,
        result.nbytes / 1e6,
    )
    return result


# ---- the built-in photographs ------------------------------------------------------------


def _photograph_pixels(photo: Photograph) -> np.ndarray:
    """The photograph as ``(H, W, 3)`` uint8 (greyscale replicated into RGB)."""
    resource = importlib.resources.files(photo.package).joinpath(*PACKAGE_DATA[photo.package], photo.filename)
    with importlib.resources.as_file(resource) as path:
        return _decode(Path(path), "builtin photograph")


def pan_zoom_windows(height: int, width: int, num_frames: int, zoom: tuple[float, float], pan: float) -> np.ndarray:
    """The square windows of a photograph's pan/zoom video: ``(num_frames, 3)`` rows
    ``(top, left, side)`` in pixels.

    With phase ``p = 2 pi f / num_frames``: zoom ``z = z0 + (z1 - z0) (1 - cos p) / 2``,
    side ``min(H, W) / z``; the centre runs a figure of eight,
    ``(H/2 + pan * room_y * sin 2p, W/2 + pan * room_x * sin p)`` with ``room`` half the
    space the window leaves. Periodic and smooth (frame ``num_frames`` would be frame 0), and
    inside the photograph for ``pan <= 1``.
    """
    phase = 2 * np.pi * np.arange(num_frames) / num_frames
    side = min(height, width) / (zoom[0] + (zoom[1] - zoom[0]) * (1 - np.cos(phase)) / 2)
    centre_y = height / 2 + pan * (height - side) / 2 * np.sin(2 * phase)
    centre_x = width / 2 + pan * (width - side) / 2 * np.sin(phase)
    return np.stack([centre_y - side / 2, centre_x - side / 2, side], axis=1)


def builtin_videos(
    difficulty: str = "medium", size: int = DEFAULT_SIZE, num_frames: int = DEFAULT_NUM_FRAMES, videos: str = "train"
) -> BackgroundVideos:
    """The offline default: the level's first photographs of ``PHOTOGRAPHS`` (``videos="val"``:
    of ``VALIDATION_PHOTOGRAPHS``) as pan/zoom videos of ``num_frames`` frames each,
    ``(V, num_frames, size, size, 3)``."""
    check_backgrounds(difficulty, None, size, num_frames, videos)
    source = "builtin" if videos == "train" else "builtin:val"
    photos = level_photographs(difficulty, videos)
    clips = []
    for photo in photos:
        pixels = _photograph_pixels(photo).astype(np.float32)
        windows = pan_zoom_windows(pixels.shape[0], pixels.shape[1], num_frames, photo.zoom, photo.pan)
        clips.append(
            np.stack([_to_uint8(_sample_window(pixels, top, left, side, side, size)) for top, left, side in windows])
        )
    return _stack(clips, [photo.name for photo in photos], source)


# ---- DAVIS-2017 --------------------------------------------------------------------------


def _decode(path: Path, what: str) -> np.ndarray:
    """An image file as ``(H, W, 3)`` uint8 RGB; a file that does not decode names itself."""
    from PIL import Image

    try:
        with Image.open(path) as image:
            return np.asarray(image.convert("RGB"))
    except (OSError, ValueError, SyntaxError) as error:
        raise ValueError(f"{what}: cannot decode frame {str(path)!r}: {error}") from error


def load_davis(
    root: str | os.PathLike, difficulty: str = "medium", size: int = DEFAULT_SIZE, videos: str = "train"
) -> BackgroundVideos:
    """The level's DAVIS-2017 training (``videos="val"``: validation) videos under ``root``,
    ``(V, F, size, size, 3)``.

    Each frame is decoded and resized (``resize_frame``) one at a time, so the peak memory
    is the result's.

    Raises:
      ValueError: as ``davis_frame_paths``, a bad ``size``, or a frame that does not decode
        (the file is named).
    """
    check_backgrounds(difficulty, size=size, videos=videos)
    paths = davis_frame_paths(root, difficulty, videos)
    clips = [
        np.stack([resize_frame(_decode(path, "background_dir"), size) for path in frames]) for frames in paths.values()
    ]
    suffix = "" if videos == "train" else ":val"
    return _stack(clips, list(paths), f"davis:{Path(root).expanduser()}{suffix}")


# ---- entry points ------------------------------------------------------------------------


def load(
    difficulty: str = "medium",
    background_dir: str | os.PathLike | None = None,
    size: int = DEFAULT_SIZE,
    num_frames: int = DEFAULT_NUM_FRAMES,
    videos: str = "train",
) -> BackgroundVideos:
    """The level's background videos: DAVIS-2017 under ``background_dir``, or (``None``) the
    built-in photographs as ``num_frames``-frame pan/zoom videos. ``size``: the square
    frame's side (see the module docstring for the memory it implies); ``videos``: the
    training set or the held-out one (``"train"``, ``"val"``)."""
    check_backgrounds(difficulty, background_dir, size, num_frames, videos)
    if background_dir is None:
        return builtin_videos(difficulty, size, num_frames, videos)
    return load_davis(background_dir, difficulty, size, videos)
