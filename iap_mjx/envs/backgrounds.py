"""Background videos for the Distracting Control Suite: loaded once, resized to the sky texture.

The reference (google-research ``distracting_control/background.py``) replaces the skybox
texture with a frame of a DAVIS-2017 video; every frame is resized to the square texture
(``tf.image.resize``: bilinear, half-pixel centres, no antialiasing, then a truncating cast
to uint8; the aspect ratio is not kept). Here every frame is resized once, at load time, to
``size x size`` and the whole set is one array ``(videos, frames, size, size, 3)`` uint8, so
that a compiled step only indexes it (the distraction layer draws the video and frame per
episode and samples the sky by ray direction).

Two sources:

- ``load_davis(root, difficulty)``: a DAVIS-2017 directory, either the dataset's own layout
  ``<root>/JPEGImages/480p/<video>/<frame>.jpg`` or ``<root>/<video>/<frame>.jpg``; frames
  sorted by file name; the videos are the first ``num_videos(difficulty)`` of the reference's
  DAVIS-2017 training list (easy 4, medium 8, hard all 60).
- ``builtin_videos(difficulty)``: works on a fresh machine with nothing downloaded. Natural
  photographs that ship inside the scikit-image wheel (``skimage/data``: public domain or
  CC0, see ``PHOTOGRAPHS`` and ``docs/backgrounds.md``), each made into a short "video" by a
  smooth, periodic pan and zoom through the photo (deterministic): ten videos, easy the first
  4, medium the first 8, hard all 10.

Each source has two disjoint sets, named as the reference names them (its
``background_dataset_videos``): ``"train"``, what training draws from, and ``"val"``, held out
for evaluating generalisation to backgrounds never seen in training: the reference's 30
DAVIS-2017 validation videos, or ten other photographs (``VALIDATION_PHOTOGRAPHS``, shipped in
scikit-image and matplotlib), with the same counts per difficulty.

``load(difficulty, background_dir=None)`` picks one (``None``: the photographs);
``check(difficulty, background_dir)`` runs the same validation without decoding an image,
cheap enough to run before any compile. Every bad setting raises ``ValueError`` naming the
setting and what is valid.

Memory: ``videos * frames * size**2 * 3`` bytes (``BackgroundVideos.nbytes``). DAVIS-2017
480p training videos have up to about 100 frames, so at the default ``size=256``
(192 KiB a frame) medium (8 videos) takes up to ~160 MB and hard (60) up to ~1.2 GB;
``size=128`` a quarter of that (~40 MB / ~300 MB). The photographs at 32 frames: 50 MB
(medium) / 63 MB (hard) at 256. The reference's texture is 800 x 800; at 240 x 320 with
dm_control's 45-degree field of view one cube face spans about 580 pixels, so 256 is about
half the screen's resolution, 128 a quarter. Pass the array to jitted code as an argument,
not as a closed-over constant (XLA would embed it in the program).
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)

DIFFICULTIES = ("easy", "medium", "hard")
VIDEO_SETS = ("train", "val")
# distracting_control/suite_utils.py: DIFFICULTY_NUM_VIDEOS (None: every video).
_NUM_VIDEOS = {"easy": 4, "medium": 8, "hard": None}
DEFAULT_SIZE = 256
DEFAULT_NUM_FRAMES = 32
FRAME_EXTENSIONS = (".jpg", ".jpeg", ".png")

# distracting_control/background.py: DAVIS17_TRAINING_VIDEOS, in the reference's order
# (a level uses the first N).
DAVIS17_TRAINING_VIDEOS = (
    "bear", "bmx-bumps", "boat", "boxing-fisheye", "breakdance-flare", "bus",
    "car-turn", "cat-girl", "classic-car", "color-run", "crossing",
    "dance-jump", "dancing", "disc-jockey", "dog-agility", "dog-gooses",
    "dogs-scale", "drift-turn", "drone", "elephant", "flamingo", "hike",
    "hockey", "horsejump-low", "kid-football", "kite-walk", "koala",
    "lady-running", "lindy-hop", "longboard", "lucia", "mallard-fly",
    "mallard-water", "miami-surf", "motocross-bumps", "motorbike", "night-race",
    "paragliding", "planes-water", "rallye", "rhino", "rollerblade",
    "schoolgirls", "scooter-board", "scooter-gray", "sheep", "skate-park",
    "snowboard", "soccerball", "stroller", "stunt", "surf", "swing", "tennis",
    "tractor-sand", "train", "tuk-tuk", "upside-down", "varanus-cage", "walking",
)
# distracting_control/background.py: DAVIS17_VALIDATION_VIDEOS, in the reference's order
# (``background_dataset_videos="val"``).
DAVIS17_VALIDATION_VIDEOS = (
    "bike-packing", "blackswan", "bmx-trees", "breakdance", "camel",
    "car-roundabout", "car-shadow", "cows", "dance-twirl", "dog", "dogs-jump",
    "drift-chicane", "drift-straight", "goat", "gold-fish", "horsejump-high",
    "india", "judo", "kite-surf", "lab-coat", "libby", "loading", "mbike-trick",
    "motocross-jump", "paragliding-launch", "parkour", "pigs", "scooter-black",
    "shooting", "soapbox",
)
_DAVIS_SUBDIR = Path("JPEGImages") / "480p"
_LAYOUTS = "<root>/JPEGImages/480p/<video>/<frame>.jpg or <root>/<video>/<frame>.jpg"


@dataclasses.dataclass(frozen=True)
class Photograph:
    """One photograph shipped in an installed package, and the pan/zoom path made from it.

    Attributes:
      name: the video's name (the package's name for the image).
      filename: the file inside the package's data directory (``PACKAGE_DATA``).
      source: who made it, where from (as the package's documentation states it).
      licence: its licence, as the package's documentation states it.
      zoom: ``(min, max)``: the window's side is ``min(H, W) / zoom``.
      pan: how far the window's centre moves, a fraction of the room the window leaves.
      package: ``"skimage"`` or ``"matplotlib"``.
    """

    name: str
    filename: str
    source: str
    licence: str
    zoom: tuple[float, float] = (1.25, 1.6)
    pan: float = 0.9
    package: str = "skimage"


# Where each package keeps its sample images.
PACKAGE_DATA = {"skimage": ("data",), "matplotlib": ("mpl-data", "sample_data")}


# Colour photographs first, so that easy and medium draw from them; all ten ship in the
# scikit-image 0.26.0 wheel (listed in its RECORD), none is fetched on demand.
PHOTOGRAPHS = (
    Photograph("astronaut", "astronaut.png", "Eileen Collins, NASA Great Images database",
               "public domain (NASA)"),
    Photograph("coffee", "coffee.png", "coffee cup, Rachel Michetti, courtesy of Pikolo Espresso Bar",
               "CC0"),
    Photograph("chelsea", "chelsea.png", "Chelsea the cat, Stefan van der Walt", "CC0"),
    Photograph("rocket", "rocket.jpg", "DSCOVR launch on Falcon 9, SpaceX Photos",
               "public domain (released by SpaceX)"),
    Photograph("hubble_deep_field", "hubble_deep_field.jpg", "Hubble eXtreme Deep Field, NASA/HubbleSite",
               "public domain (NASA)"),
    # A fundus photograph is a bright disc on black: stay near its centre.
    Photograph("retina", "retina.jpg", "fundus photograph, Mikael Haggstrom, Wikimedia Commons",
               "CC0", zoom=(2.0, 2.5), pan=0.3),
    Photograph("camera", "camera.png", "photographer with a camera, Lav Varshney (greyscale)", "CC0"),
    Photograph("brick", "brick.png", "brick wall, CC0Textures Bricks25 (greyscale)", "CC0"),
    Photograph("grass", "grass.png", "grass, linolafett on DeviantArt (greyscale)", "CC0"),
    Photograph("gravel", "gravel.png", "gravel, CC0Textures Gravel04 (greyscale)", "CC0"),
)

# Held out: none of these is in PHOTOGRAPHS. Colour first, as above; the set has fewer colour
# photographs (3 of 10, against 6), so it also moves the colour statistics away from training.
VALIDATION_PHOTOGRAPHS = (
    Photograph("motorcycle_left", "motorcycle_left.png",
               "Middlebury 2014 stereo benchmark (Nesic, Westling, Wang, Kitajima, Krathwohl, "
               "Scharstein), left view", "not stated by scikit-image (Middlebury's research data)"),
    Photograph("immunohistochemistry", "ihc.png",
               "colonic glands, IHC staining, Center for Microscopy And Molecular Imaging",
               "no known copyright restrictions"),
    Photograph("grace_hopper", "grace_hopper.jpg", "Rear Admiral Grace Hopper, U.S. Navy photograph",
               "public domain (U.S. Navy)", package="matplotlib"),
    Photograph("coins", "coins.png", "Greek coins from Pompeii, Brooklyn Museum (greyscale)",
               "no known copyright restrictions"),
    Photograph("clock", "clock_motion.png", "motion-blurred wall clock, Stefan van der Walt (greyscale)",
               "public domain"),
    Photograph("cell", "cell.png", "cell in saline, quantitative phase image, Paul Mueller (greyscale)",
               "CC0"),
    Photograph("text", "text.png", "text for corner detection, Wikipedia File:Corner.png (greyscale)",
               "public domain"),
    Photograph("moon", "moon.png", "surface of the moon (greyscale)", "not stated by scikit-image"),
    Photograph("page", "page.png", "scanned page of printed text (greyscale)",
               "not stated by scikit-image"),
    Photograph("microaneurysms", "microaneurysms.png",
               "retina detail, HRF fundus image database, Andreas Maier (greyscale)", "CC0",
               zoom=(1.1, 1.3), pan=0.5),
)


@dataclasses.dataclass(frozen=True, eq=False)
class BackgroundVideos:
    """A set of background videos, every frame ``size x size``.

    Attributes:
      frames: ``(V, F, S, S, 3)`` uint8. ``F`` is the longest video's frame count; a shorter
        video is padded by repeating its last frame, so every index ``< F`` is one of its
        real frames, but a sampler must draw frame indices below ``lengths[v]``.
      lengths: ``(V,)`` int32, each video's true frame count (``1 <= lengths <= F``).
      names: the ``V`` video names.
      source: where they came from (``"davis:<dir>"`` or ``"builtin"``).
    """

    frames: np.ndarray
    lengths: np.ndarray
    names: tuple[str, ...]
    source: str

    def __post_init__(self):
        frames, lengths = self.frames, self.lengths
        if frames.dtype != np.uint8 or frames.ndim != 5 or frames.shape[-1] != 3 or frames.shape[2] != frames.shape[3]:
            raise ValueError(f"BackgroundVideos.frames must be uint8 (V, F, S, S, 3), got {frames.dtype} {frames.shape}.")
        if lengths.dtype != np.int32 or lengths.shape != frames.shape[:1]:
            raise ValueError(f"BackgroundVideos.lengths must be int32 ({frames.shape[0]},), got {lengths.dtype} "
                             f"{lengths.shape}.")
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


# ---- settings ----------------------------------------------------------------------------


def num_videos(difficulty: str) -> int | None:
    """The number of videos a difficulty uses (``None``: all of them)."""
    if difficulty not in _NUM_VIDEOS:
        raise ValueError(f"Unknown difficulty {difficulty!r}; valid: {', '.join(DIFFICULTIES)}.")
    return _NUM_VIDEOS[difficulty]


def _check_count(name: str, value: int) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ValueError(f"background {name} must be an int >= 1, got {value!r}.")


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
    of ``pixels`` ``(H, W, 3)`` float32; float32 ``(size, size, 3)``."""
    rows = _axis_taps(pixels.shape[0], size, top, height)
    cols = _axis_taps(pixels.shape[1], size, left, width)
    top_row, bottom_row = rows[0][:, None], rows[1][:, None]
    left_col, right_col = cols[0][None, :], cols[1][None, :]
    x_weight = cols[2][None, :, None]
    top_left, top_right = pixels[top_row, left_col], pixels[top_row, right_col]
    bottom_left, bottom_right = pixels[bottom_row, left_col], pixels[bottom_row, right_col]
    top_values = top_left + (top_right - top_left) * x_weight
    bottom_values = bottom_left + (bottom_right - bottom_left) * x_weight
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
    frames = np.stack([
        np.concatenate([video, np.repeat(video[-1:], longest - len(video), axis=0)]) for video in videos
    ])
    result = BackgroundVideos(frames=frames, lengths=lengths, names=tuple(names), source=source)
    logger.info("background videos from %s: %d videos, %d frames (padded), %dx%d, %.1f MB",
                source, result.num_videos, result.num_frames, result.size, result.size, result.nbytes / 1e6)
    return result


def _first(sequence: Sequence, difficulty: str) -> tuple:
    count = num_videos(difficulty)
    return tuple(sequence if count is None else sequence[:count])


def _check_videos(videos: str) -> None:
    if videos not in VIDEO_SETS:
        raise ValueError(f"background_videos = {videos!r}: valid {', '.join(VIDEO_SETS)} (training or "
                         "held-out backgrounds)")


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


def builtin_videos(difficulty: str = "medium", size: int = DEFAULT_SIZE,
                   num_frames: int = DEFAULT_NUM_FRAMES, videos: str = "train") -> BackgroundVideos:
    """The offline default: the level's first photographs of ``PHOTOGRAPHS`` (``videos="val"``:
    of ``VALIDATION_PHOTOGRAPHS``) as pan/zoom videos of ``num_frames`` frames each,
    ``(V, num_frames, size, size, 3)``."""
    _check_videos(videos)
    source = "builtin" if videos == "train" else "builtin:val"
    photos = _first(PHOTOGRAPHS if videos == "train" else VALIDATION_PHOTOGRAPHS, difficulty)
    _check_count("size", size)
    _check_count("num_frames", num_frames)
    clips = []
    for photo in photos:
        pixels = _photograph_pixels(photo).astype(np.float32)
        windows = pan_zoom_windows(pixels.shape[0], pixels.shape[1], num_frames, photo.zoom, photo.pan)
        clips.append(np.stack([
            _to_uint8(_sample_window(pixels, top, left, side, side, size)) for top, left, side in windows
        ]))
    return _stack(clips, [photo.name for photo in photos], source)


# ---- DAVIS-2017 --------------------------------------------------------------------------


def davis_frame_paths(root: str | os.PathLike, difficulty: str = "medium",
                      videos: str = "train") -> dict[str, list[Path]]:
    """The frame files of the level's DAVIS-2017 training videos (``videos="val"``: validation
    videos) under ``root``, each video's sorted by file name; checks everything that can be
    checked without decoding.

    Raises:
      ValueError: unknown difficulty; ``root`` missing or not a directory; a listed video
        missing (all missing ones are named); a video directory without frames.
    """
    _check_videos(videos)
    kind = "training" if videos == "train" else "validation"
    videos = _first(DAVIS17_TRAINING_VIDEOS if videos == "train" else DAVIS17_VALIDATION_VIDEOS, difficulty)
    root = Path(root).expanduser()
    if not root.is_dir():
        raise ValueError(f"background_dir {str(root)!r} does not exist or is not a directory; give a DAVIS-2017 "
                         f"directory ({_LAYOUTS}) or None for the built-in photographs.")
    video_root = root / _DAVIS_SUBDIR if (root / _DAVIS_SUBDIR).is_dir() else root
    missing = [name for name in videos if not (video_root / name).is_dir()]
    if missing:
        raise ValueError(
            f"background_dir {str(video_root)!r} lacks {len(missing)} of the {len(videos)} DAVIS-2017 {kind} "
            f"videos that difficulty {difficulty!r} uses: missing {missing}; expected {_LAYOUTS} with the videos "
            f"{list(videos)}.")
    paths = {}
    for name in videos:
        frames = sorted(
            path for path in (video_root / name).iterdir()
            if path.is_file() and not path.name.startswith(".") and path.suffix.lower() in FRAME_EXTENSIONS
        )
        if not frames:
            raise ValueError(f"background_dir: video {name!r} ({str(video_root / name)!r}) holds no frames "
                             f"(files ending in {', '.join(FRAME_EXTENSIONS)}).")
        paths[name] = frames
    return paths


def _decode(path: Path, what: str) -> np.ndarray:
    """An image file as ``(H, W, 3)`` uint8 RGB; a file that does not decode names itself."""
    from PIL import Image

    try:
        with Image.open(path) as image:
            return np.asarray(image.convert("RGB"))
    except (OSError, ValueError, SyntaxError) as error:
        raise ValueError(f"{what}: cannot decode frame {str(path)!r}: {error}") from error


def load_davis(root: str | os.PathLike, difficulty: str = "medium", size: int = DEFAULT_SIZE,
               videos: str = "train") -> BackgroundVideos:
    """The level's DAVIS-2017 training (``videos="val"``: validation) videos under ``root``,
    ``(V, F, size, size, 3)``.

    Each frame is decoded and resized (``resize_frame``) one at a time, so the peak memory
    is the result's.

    Raises:
      ValueError: as ``davis_frame_paths``, a bad ``size``, or a frame that does not decode
        (the file is named).
    """
    _check_count("size", size)
    paths = davis_frame_paths(root, difficulty, videos)
    clips = [
        np.stack([resize_frame(_decode(path, "background_dir"), size) for path in frames])
        for frames in paths.values()
    ]
    suffix = "" if videos == "train" else ":val"
    return _stack(clips, list(paths), f"davis:{Path(root).expanduser()}{suffix}")


# ---- entry points ------------------------------------------------------------------------


def check(difficulty: str, background_dir: str | os.PathLike | None = None, size: int = DEFAULT_SIZE,
          num_frames: int = DEFAULT_NUM_FRAMES, videos: str = "train") -> None:
    """Validates ``load``'s arguments without decoding any image (run it before compiling).

    Raises:
      ValueError: as ``load`` would, except for frames that do not decode.
    """
    num_videos(difficulty)
    _check_videos(videos)
    _check_count("size", size)
    _check_count("num_frames", num_frames)
    if background_dir is not None:
        davis_frame_paths(background_dir, difficulty, videos)


def load(difficulty: str = "medium", background_dir: str | os.PathLike | None = None, size: int = DEFAULT_SIZE,
         num_frames: int = DEFAULT_NUM_FRAMES, videos: str = "train") -> BackgroundVideos:
    """The level's background videos: DAVIS-2017 under ``background_dir``, or (``None``) the
    built-in photographs as ``num_frames``-frame pan/zoom videos. ``size``: the square
    frame's side (see the module docstring for the memory it implies); ``videos``: the
    training set or the held-out one (``"train"``, ``"val"``)."""
    check(difficulty, background_dir, size, num_frames, videos)
    if background_dir is None:
        return builtin_videos(difficulty, size, num_frames, videos)
    return load_davis(background_dir, difficulty, size, videos)

