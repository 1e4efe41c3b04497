"""An env's settings: ``EnvConfig`` (frozen, hashable, validated on construction).

Every field can be set from a training config's ``env.<field>=<value>`` override or as a
keyword of ``iap_mjx.envs.make(name, ...)``; a bad value raises ``ValueError`` naming the
field and its valid values before any model is built.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from iap_mjx.checks import is_int, require_choice, require_int, require_number
from iap_mjx.configs.distraction import DIFFICULTIES, DistractionConfig

PIXEL_MODES = ("pixels", "pixels_depth", "pixels+state", "depth+state")
"""The observation modes ``iap_mjx.envs.pixels`` renders."""
CAMERA_SETTINGS = ("camera_id", "height", "width", "frame_stack")
"""``EnvConfig``'s camera settings: the pixel modes' only."""
DEPTH_MAX = 4.0
"""Metres of depth that ``"depth+state"`` maps onto ``[0, 1]`` unless ``depth_max`` says
otherwise: on ``quadruped-gates`` the next gate (at most 2.8 m past the one just passed) and
what stands between."""
OBS_MODES = ("state",) + PIXEL_MODES
SOLVERS = ("newton", "cg")  # QuadrupedConfig.solver: MuJoCo's mjSOL_NEWTON, mjSOL_CG

DISTRACTION_FIELDS = {
    "distraction": "difficulty",
    "dynamic": "dynamic",
    "distraction_kinds": "kinds",
    "background_dir": "background_dir",
    "background_size": "background_size",
    "background_frames": "background_frames",
    "background_videos": "background_videos",
}
"""The ``EnvConfig`` fields of the distraction and the ``DistractionConfig`` field each sets
(the names stay those typed on a command line: ``env.distraction=medium``)."""
DISTRACTION_SETTINGS = tuple(name for name in DISTRACTION_FIELDS if name != "distraction")
"""The ``EnvConfig`` fields that belong to ``distraction`` (meaningless without one)."""


def check_depth_max(depth_max: Any, obs_mode: str, owner: str = "") -> None:
    """Raises ``ValueError`` unless ``depth_max`` is ``None`` or, with ``obs_mode``
    ``"depth+state"`` (the one mode that scales depth), a finite number of metres > 0."""
    if depth_max is None:
        return
    if obs_mode != "depth+state":
        raise ValueError(
            f"{owner}depth_max = {depth_max!r} scales the depth of obs_mode 'depth+state' only, "
            f"got obs_mode={obs_mode!r}; leave depth_max unset (None) or set obs_mode='depth+state'."
        )
    require_number(f"{owner}depth_max", depth_max, 0, low_open=True, high_open=True, unit="m")


def _check_slots(setting: str, value: Any) -> None:
    """A budget of MJX slots: ``"task"``, ``"all"`` (the attribute's docstring says what each
    means) or an int >= 1."""
    if value not in ("task", "all") and not (is_int(value) and value >= 1):
        raise ValueError(f'{setting} must be "task", "all" or an int >= 1, got {value!r}.')


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Static settings of one env (hashable, so jitted code can depend on it).

    Attributes:
      action_repeat: control steps per env step (the action is held; rewards are summed).
      episode_length: env steps per episode; ``None`` means the task's default control steps
        (dm_control's 1000; ``quadruped-flat``'s and ``quadruped-turn``'s 500) over ``action_repeat``, rounded up
        (``envs.episode_length`` reads it without building the env).
      solver_iterations: MJX constraint-solver iterations (MuJoCo ``opt.iterations``).
      ls_iterations: MJX line-search iterations (MuJoCo ``opt.ls_iterations``).
      max_contacts: contact slots MJX keeps per step (its ``max_contact_points``: the
        closest candidate contacts win). MJX otherwise carries a constraint row block for
        every candidate geom pair at every step where native MuJoCo carries only the
        touching ones (on cheetah, a few of some thirty candidates), and the solver's cost
        grows with the rows (BENCHMARKS.md, the physics section's contact-slot rows).
        ``"task"`` is the task's measured default (``DmControlEnv.default_max_contacts``), ``"all"`` keeps
        every candidate, an int sets the number. ``metrics["contact_saturated"]`` reports
        an episode in which every kept slot was touching at once (a contact may have
        been dropped).
      max_abs_state: an env whose ``|qpos|`` or ``|qvel|`` exceeds this (or is not finite)
        is ended as a bad state.
      obs_mode: ``"state"`` (the env's own observation) or a pixel mode handled by
        ``iap_mjx.envs.pixels``.
      camera_id, height, width, frame_stack: the camera settings for pixel modes (setting one
        with ``obs_mode="state"`` is an error, not silently ignored).
      depth_max: ``"depth+state"`` only: its depth is ``min(depth, depth_max) / depth_max``,
        in ``[0, 1]`` (metres along the optical axis, 1 at ``depth_max`` and beyond);
        ``None`` means :data:`DEPTH_MAX` (4 m). Setting it with another ``obs_mode`` is an
        error, not silently ignored.
      distraction: the Distracting Control Suite's difficulty, ``"easy"``, ``"medium"`` or
        ``"hard"`` (``None`` or ``"none"``: no distraction); pixel modes of the suite's six
        tasks, camera 0 only; see ``iap_mjx.envs.distraction``. The settings below belong to
        it: setting one without ``distraction`` is an error, not silently ignored. They are
        ``DistractionConfig``'s (``iap_mjx.configs.distraction``, which validates them; the
        names map by :data:`DISTRACTION_FIELDS`); ``None`` means its default.
      dynamic: distractions move every control step (else one draw per episode).
      distraction_kinds: which are on: a subset of ``background``, ``camera``, ``colour``
        (a tuple or a comma-separated string; ``None``: all three).
      background_dir: a DAVIS-2017 directory for the backgrounds (``None``: the photographs
        that ship in scikit-image and matplotlib, ``iap_mjx.envs.backgrounds``); needs the background kind.
      background_size, background_frames: the square sky texture's side in texels, and the
        frames per built-in video (``None``: ``distraction.DEFAULT_SIZE`` /
        ``DEFAULT_NUM_FRAMES``).
      background_videos: ``"train"`` (``None`` too), the backgrounds training draws from, or
        ``"val"``, a disjoint held-out set for evaluating generalisation (the reference's 30
        DAVIS-2017 validation videos, or other built-in photographs: ``docs/backgrounds.md``).
    """

    action_repeat: int = 1
    episode_length: int | None = None
    solver_iterations: int = 8
    ls_iterations: int = 4
    max_contacts: int | str = "task"
    max_abs_state: float = 1e6
    obs_mode: str = "state"
    camera_id: int = 0
    height: int = 100
    width: int = 100
    frame_stack: int = 1
    depth_max: float | None = None
    distraction: str | None = None
    dynamic: bool = False
    distraction_kinds: tuple[str, ...] | str | None = None
    background_dir: str | None = None
    background_size: int | None = None
    background_frames: int | None = None
    background_videos: str | None = None

    def __post_init__(self):
        positive_ints = ("action_repeat", "solver_iterations", "ls_iterations", "height", "width", "frame_stack")
        for name in positive_ints:
            require_int(f"env.{name}", getattr(self, name))
        _check_slots("env.max_contacts", self.max_contacts)
        require_int("env.episode_length", self.episode_length, none_ok=True)
        require_number("env.max_abs_state", self.max_abs_state, 0, low_open=True)
        require_choice("env.obs_mode", self.obs_mode, OBS_MODES)
        require_int("env.camera_id", self.camera_id, 0)
        check_depth_max(self.depth_max, self.obs_mode, "env.")
        self._check_camera()
        self._check_distraction()

    def _check_camera(self) -> None:
        """The camera settings belong to the pixel modes: set with ``obs_mode="state"`` they
        would change nothing, so they are an error, not silently ignored."""
        if self.obs_mode != "state":
            return
        defaults = {field.name: field.default for field in dataclasses.fields(self)}  # a subclass's own
        given = [f"{name}={getattr(self, name)!r}" for name in CAMERA_SETTINGS if getattr(self, name) != defaults[name]]
        if given:
            raise ValueError(
                f"env: {', '.join(given)} set the camera of a pixel obs_mode, but obs_mode is 'state'; "
                f"set env.obs_mode to one of {', '.join(PIXEL_MODES)}, or leave them unset."
            )

    def _check_distraction(self) -> None:
        """The settings ``DistractionConfig`` cannot check alone: none without a distraction,
        a pixel ``obs_mode``, camera 0 for the camera kind. Stores the canonical forms of
        ``distraction_kinds`` and ``background_dir``, so equal settings make equal configs."""
        if self.distraction == "none":
            object.__setattr__(self, "distraction", None)
        if self.distraction is None:
            given = [f"{name}={value!r}" for name, value in self._distraction_settings().items()]
            if given:
                raise ValueError(
                    f"env: {', '.join(given)} set without a distraction; set "
                    f"env.distraction to one of {', '.join(DIFFICULTIES)}."
                )
            return
        if self.obs_mode == "state":
            raise ValueError(
                f"env.distraction = {self.distraction!r} needs a pixel obs_mode "
                f"(one of {PIXEL_MODES}), got obs_mode='state'."
            )
        config = self.distraction_config()
        assert config is not None  # a distraction is set
        for name in ("distraction_kinds", "background_dir"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, getattr(config, DISTRACTION_FIELDS[name]))
        if "camera" in config.kinds and self.camera_id != 0:
            raise ValueError(
                f"env.camera_id = {self.camera_id}: the camera distraction perturbs the "
                "suite's camera 0 (valid camera_id: 0), or leave 'camera' out of "
                "distraction_kinds."
            )

    def _distraction_settings(self) -> dict[str, Any]:
        """The :data:`DISTRACTION_SETTINGS` set away from their defaults (``None``, and
        ``False`` for ``dynamic``: compared by identity, so ``0`` is not ``False``)."""
        defaults = {field.name: field.default for field in dataclasses.fields(EnvConfig)}
        return {name: getattr(self, name) for name in DISTRACTION_SETTINGS if getattr(self, name) is not defaults[name]}

    def distraction_config(self) -> DistractionConfig | None:
        """The ``DistractionConfig`` of these settings (``None`` without one); building it
        validates them, background directory included, without decoding an image."""
        if self.distraction is None:
            return None
        given = {DISTRACTION_FIELDS[name]: value for name, value in self._distraction_settings().items()}
        return DistractionConfig(difficulty=self.distraction, **given)


@dataclasses.dataclass(frozen=True)
class QuadrupedConfig(EnvConfig):
    """``EnvConfig`` plus the quadruped's settings (``iap_mjx.envs.quadruped``). The camera
    size defaults to the first-person camera's 32x24 (``camera_id`` 0 is that camera);
    ``episode_length=None`` means the task's own (500 control steps on the flat, 1000 on the
    course).

    Attributes:
      action_repeat: 1 only (the PMTG policies act once per 0.02 s control step).
      v_cap: the reward's speed cap in m/s (per control step: ``v_cap * 0.02`` m). 1 m/s by
        default: twice the walking speed aimed for, so walking well is paid in full and
        lunges or falls forward (many times that per 0.02 s step) are not.
      joint_noise: the first joint angles are the standing pose plus uniform noise of this
        half-width (rad).
      fall_penalty: metres taken from the return at the control step that ends the episode
        early: the trunk on the ground, or off the platform or out of the corridor anywhere
        but past the course's end. 0 (the default): a fall costs only the distance not walked.
      max_geom_pairs: candidate geom pairs MJX runs each collision function on per step (its
        ``max_geom_pairs``: the pairs whose bounding spheres are nearest win; plane pairs are
        never culled). ``"task"`` is the task's default (no culling: the course has one
        colliding wall, so no group has a pair that cannot touch), ``"all"`` runs every pair,
        an int sets it. ``metrics["contact_saturated"]`` also reports an episode in which
        more pairs of a culled group had overlapping bounding spheres than were kept.
      solver: MuJoCo's constraint solver, ``"newton"`` or ``"cg"``.
      solver_iterations, ls_iterations: as in ``EnvConfig``; the quadruped's defaults (and
        ``solver``'s) are its MJCF's (``iap_mjx.robots.a1``: ``SOLVER``, ``ITERATIONS``,
        ``LS_ITERATIONS``), chosen by the solver sweep in BENCHMARKS.md; repeated here as
        literals, since configs import no JAX (a test holds them equal).
    """

    solver_iterations: int = 8
    ls_iterations: int = 4
    height: int = 24
    width: int = 32
    v_cap: float = 1.0
    joint_noise: float = 0.05
    fall_penalty: float = 0.0
    max_geom_pairs: int | str = "task"
    solver: str = "newton"

    def __post_init__(self):
        super().__post_init__()
        if self.action_repeat != 1:
            # the PMTG trajectory generator advances its phase by one control step (0.02 s) per
            # action, and the course's statistics count control steps
            raise ValueError(
                f"env.action_repeat must be 1 (one action per 0.02 s control step), got {self.action_repeat!r}."
            )
        require_number("env.v_cap", self.v_cap, 0, low_open=True, unit="m/s")
        require_number("env.joint_noise", self.joint_noise, 0, 0.5, unit="rad")
        require_number("env.fall_penalty", self.fall_penalty, 0, unit="m")
        _check_slots("env.max_geom_pairs", self.max_geom_pairs)
        require_choice("env.solver", self.solver, SOLVERS)


@dataclasses.dataclass(frozen=True)
class QuadrupedWallsConfig(QuadrupedConfig):
    """``QuadrupedConfig`` plus the course's settings (``quadruped-walls`` only; the flat has
    no walls, so ``quadruped-flat`` refuses ``n_walls``).

    Attributes:
      n_walls: walls on the course (a static shape).
    """

    n_walls: int = 3

    def __post_init__(self):
        super().__post_init__()
        require_int("env.n_walls", self.n_walls)


@dataclasses.dataclass(frozen=True)
class QuadrupedTurnConfig(QuadrupedConfig):
    """``QuadrupedConfig`` plus the turn command's scale (``quadruped-turn`` only).

    Attributes:
      max_turn_rate: the yaw rate (rad/s) a command of +-1 asks for. 0.5 by default: at the
        full command a quarter turn takes about 3 s, and a robot walking 0.8 m/s (the PMTG
        trot's speed, RESULTS.md section ``quadruped-walking``) moves about 1 m sideways over
        the 1.9 m that at least separate two of the course's walls, more than a wall's
        0.6-1.0 m gap needs.
    """

    max_turn_rate: float = 0.5

    def __post_init__(self):
        super().__post_init__()
        require_number("env.max_turn_rate", self.max_turn_rate, 0, 3, low_open=True, unit="rad/s")


@dataclasses.dataclass(frozen=True)
class QuadrupedGatesConfig(QuadrupedConfig):
    """``QuadrupedConfig`` plus the gates corridor's settings (``quadruped-gates`` only).

    Attributes:
      n_gates: gates along the corridor, each followed by one clutter box (a static shape:
        the corridor is ``2.5 n_gates + 2.5`` m long, ``iap_mjx.envs.quadruped_gates``).
    """

    n_gates: int = 3

    def __post_init__(self):
        super().__post_init__()
        require_int("env.n_gates", self.n_gates)
