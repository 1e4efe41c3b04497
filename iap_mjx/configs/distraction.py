"""The Distracting Control Suite's settings: its tasks, difficulties and kinds, and the checks of
a background setting.

This is the one home of the suite's settings, and it lives in ``configs`` because a config is
validated when it is built, without MuJoCo and before any model is built: ``EnvConfig`` turns
its distraction fields into a :class:`DistractionConfig`, whose checks (the background
directory's videos included) are plain Python. The layers that do the work import from here:
``iap_mjx.envs.distraction`` (the perturbations) and ``iap_mjx.envs.backgrounds`` (the videos'
pixels); nothing here imports them.

- :data:`TASKS`: the suite's six tasks; :data:`DIFFICULTY_SCALE` and :func:`num_videos`: what a
  difficulty sets (the reference's ``suite_utils``); :data:`KINDS`: the perturbations.
- :func:`check_backgrounds` validates a background setting (the reference's DAVIS-2017
  lists, or the photographs that ship in scikit-image and matplotlib: the sets of
  :mod:`~iap_mjx.configs.background_sets`) without decoding an image.
- :class:`DistractionConfig`: one setting, validated on construction.

The background sets themselves, the video lists and the photographs, are data in
:mod:`iap_mjx.configs.background_sets`.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

from iap_mjx.checks import require_bool, require_int
from iap_mjx.configs.background_sets import (
    DAVIS17_TRAINING_VIDEOS,
    DAVIS17_VALIDATION_VIDEOS,
    PHOTOGRAPHS,
    VALIDATION_PHOTOGRAPHS,
    Photograph,
)

TASKS = ("cheetah-run", "walker-walk", "cartpole-swingup", "ball_in_cup-catch", "reacher-easy", "finger-spin")
"""The suite's tasks (the reference's six domains; each renders camera 0, fixed or trackcom)."""
KINDS = ("background", "camera", "colour")
# distracting_control/suite_utils.py: DIFFICULTY_SCALE and DIFFICULTY_NUM_VIDEOS (None: every video).
DIFFICULTY_SCALE = {"easy": 0.1, "medium": 0.2, "hard": 0.3}
_NUM_VIDEOS = {"easy": 4, "medium": 8, "hard": None}
DIFFICULTIES = tuple(DIFFICULTY_SCALE)
VIDEO_SETS = ("train", "val")
DEFAULT_SIZE = 256
DEFAULT_NUM_FRAMES = 32
MAX_BACKGROUND_SIZE = 1024
MAX_BACKGROUND_BYTES = 2 << 30
"""Limits on the device array of background frames (packed int32: 4 bytes a texel)."""
FRAME_EXTENSIONS = (".jpg", ".jpeg", ".png")

_DAVIS_SUBDIR = Path("JPEGImages") / "480p"
_LAYOUTS = "<root>/JPEGImages/480p/<video>/<frame>.jpg or <root>/<video>/<frame>.jpg"


# ---- names -------------------------------------------------------------------------------


def check_task(name: object) -> None:
    """Raises ``ValueError`` unless ``name`` is one of the suite's :data:`TASKS`."""
    if name not in TASKS:
        raise ValueError(f"distraction: {name!r} is not a Distracting Control Suite task; valid: {', '.join(TASKS)}.")


def parse_kinds(kinds: Any) -> tuple[str, ...]:
    """``kinds`` (a tuple, or a comma-separated string as typed on a command line) as a
    tuple in canonical order; unknown, repeated or no kinds raise ``ValueError``."""
    items = tuple(k.strip() for k in kinds.split(",")) if isinstance(kinds, str) else tuple(kinds)
    unknown = [k for k in items if k not in KINDS]
    if unknown or not items or len(set(items)) != len(items):
        raise ValueError(f"distraction_kinds {kinds!r}: give one or more of {', '.join(KINDS)}, each at most once.")
    return tuple(k for k in KINDS if k in items)


def num_videos(difficulty: str) -> int | None:
    """The number of videos a difficulty uses (``None``: all of them)."""
    if difficulty not in _NUM_VIDEOS:
        raise ValueError(f"Unknown difficulty {difficulty!r}; valid: {', '.join(DIFFICULTIES)}.")
    return _NUM_VIDEOS[difficulty]


# ---- background sets ---------------------------------------------------------------------


_SETTING_OF = {"size": "env.background_size", "num_frames": "env.background_frames"}


def _check_count(name: str, value: int) -> None:
    """``name``: ``backgrounds.load``'s argument, named with the env setting that gives it."""
    require_int(f"background {name} (the setting {_SETTING_OF[name]})", value)


def _check_video_set(videos: str) -> None:
    if videos not in VIDEO_SETS:
        raise ValueError(
            f"background_videos = {videos!r}: valid {', '.join(VIDEO_SETS)} (training or held-out backgrounds)"
        )


def _first(sequence: tuple, difficulty: str) -> tuple:
    count = num_videos(difficulty)
    return tuple(sequence if count is None else sequence[:count])


def level_photographs(difficulty: str, videos: str = "train") -> tuple[Photograph, ...]:
    """The photographs a level shows: the first ``num_videos(difficulty)`` of
    :data:`PHOTOGRAPHS` (``videos="val"``: of :data:`VALIDATION_PHOTOGRAPHS`)."""
    _check_video_set(videos)
    return _first(PHOTOGRAPHS if videos == "train" else VALIDATION_PHOTOGRAPHS, difficulty)


def davis_frame_paths(
    root: str | os.PathLike, difficulty: str = "medium", videos: str = "train"
) -> dict[str, list[Path]]:
    """The frame files of the level's DAVIS-2017 training videos (``videos="val"``: validation
    videos) under ``root``, each video's sorted by file name; checks everything that can be
    checked without decoding.

    Raises:
      ValueError: unknown difficulty; ``root`` missing or not a directory; a listed video
        missing (all missing ones are named); a video directory without frames.
    """
    _check_video_set(videos)
    kind = "training" if videos == "train" else "validation"
    names = _first(DAVIS17_TRAINING_VIDEOS if videos == "train" else DAVIS17_VALIDATION_VIDEOS, difficulty)
    root = Path(root).expanduser()
    if not root.is_dir():
        raise ValueError(
            f"background_dir {str(root)!r} does not exist or is not a directory; give a DAVIS-2017 "
            f"directory ({_LAYOUTS}) or None for the built-in photographs."
        )
    video_root = root / _DAVIS_SUBDIR if (root / _DAVIS_SUBDIR).is_dir() else root
    missing = [name for name in names if not (video_root / name).is_dir()]
    if missing:
        raise ValueError(
            f"background_dir {str(video_root)!r} lacks {len(missing)} of the {len(names)} DAVIS-2017 {kind} "
            f"videos that difficulty {difficulty!r} uses: missing {missing}; expected {_LAYOUTS} with the videos "
            f"{list(names)}."
        )
    paths = {}
    for name in names:
        frames = sorted(
            path
            for path in (video_root / name).iterdir()
            if path.is_file() and not path.name.startswith(".") and path.suffix.lower() in FRAME_EXTENSIONS
        )
        if not frames:
            raise ValueError(
                f"background_dir: video {name!r} ({str(video_root / name)!r}) holds no frames "
                f"(files ending in {', '.join(FRAME_EXTENSIONS)})."
            )
        paths[name] = frames
    return paths


def check_backgrounds(
    difficulty: str,
    background_dir: str | os.PathLike | None = None,
    size: int = DEFAULT_SIZE,
    num_frames: int = DEFAULT_NUM_FRAMES,
    videos: str = "train",
) -> None:
    """Validates ``iap_mjx.envs.backgrounds.load``'s arguments without decoding any image
    (run it before compiling).

    Raises:
      ValueError: as ``load`` would, except for frames that do not decode.
    """
    num_videos(difficulty)
    _check_video_set(videos)
    _check_count("size", size)
    _check_count("num_frames", num_frames)
    if background_dir is not None:
        davis_frame_paths(background_dir, difficulty, videos)


# ---- the setting -------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class DistractionConfig:
    """Which distractions (hashable; validated on construction, before anything compiles).

    Attributes:
      difficulty: ``"easy"``, ``"medium"`` or ``"hard"``.
      dynamic: perturbations move every control step (else one draw per episode).
      kinds: the perturbations on, a subset of ``("background", "camera", "colour")`` (a
        comma-separated string is parsed; kept in canonical order).
      background_dir: a DAVIS-2017 directory (a path is kept as a ``str``), or ``None`` for
        the photographs that ship in scikit-image and matplotlib (:data:`PHOTOGRAPHS`).
      background_size: side of the square frames (the sky texture), in texels.
      background_frames: frames per built-in video.
      background_videos: ``"train"``, the backgrounds training draws from, or ``"val"``, a
        disjoint held-out set (the reference's ``background_dataset_videos``).
    """

    difficulty: str = "medium"
    dynamic: bool = False
    kinds: tuple[str, ...] = KINDS
    background_dir: str | None = None
    background_size: int = DEFAULT_SIZE
    background_frames: int = DEFAULT_NUM_FRAMES
    background_videos: str = "train"

    def __post_init__(self):
        if not isinstance(self.difficulty, str) or self.difficulty not in DIFFICULTY_SCALE:
            raise ValueError(
                f"distraction = {self.difficulty!r} is not a difficulty; valid: "
                f"{', '.join(DIFFICULTIES)}, or none (None from Python) for no distraction."
            )
        require_bool("dynamic", self.dynamic)
        kinds = parse_kinds(self.kinds)
        object.__setattr__(self, "kinds", kinds)
        if isinstance(self.background_dir, os.PathLike):
            object.__setattr__(self, "background_dir", os.fspath(self.background_dir))
        if self.background_dir is not None and not isinstance(self.background_dir, str):
            raise ValueError(f"background_dir must be a path (str), got {self.background_dir!r}.")
        for name in ("background_size", "background_frames"):
            require_int(name, getattr(self, name))
        if self.background_size > MAX_BACKGROUND_SIZE:
            raise ValueError(
                f"background_size = {self.background_size} texels: valid 1 to "
                f"{MAX_BACKGROUND_SIZE} (the reference's sky is 800)."
            )
        if "background" not in kinds:
            for name, unset in (("background_dir", None), ("background_videos", "train")):
                if getattr(self, name) != unset:
                    raise ValueError(
                        f"{name} = {getattr(self, name)!r} is set but the background "
                        f"distraction is off (distraction_kinds = {','.join(kinds)}); add "
                        f"'background' to distraction_kinds or drop {name}."
                    )
            return
        check_backgrounds(
            self.difficulty, self.background_dir, self.background_size, self.background_frames, self.background_videos
        )
        self._check_background_bytes()

    def _check_background_bytes(self) -> None:
        """Refuses a background array over :data:`MAX_BACKGROUND_BYTES`, counted from the
        file listing (the photographs, or the longest DAVIS video) before any decoding."""
        if self.background_dir is None:
            frames = len(level_photographs(self.difficulty, self.background_videos)) * self.background_frames
        else:
            paths = davis_frame_paths(self.background_dir, self.difficulty, self.background_videos)
            frames = len(paths) * max(len(p) for p in paths.values())
        nbytes = frames * self.background_size**2 * 4
        if nbytes > MAX_BACKGROUND_BYTES:
            raise ValueError(
                f"background_size = {self.background_size}: {frames} background frames "
                f"would take {nbytes / 2**30:.1f} GiB (limit {MAX_BACKGROUND_BYTES / 2**30:.0f} "
                "GiB); lower background_size (or background_frames, or the difficulty)."
            )

    @property
    def scale(self) -> float:
        return DIFFICULTY_SCALE[self.difficulty]
