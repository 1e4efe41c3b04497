"""The Distracting Control Suite (Stone et al. 2021) inside the compiled program.

The reference is google-research ``distracting_control/`` (``suite.py``, ``suite_utils.py``,
``camera.py``, ``color.py``, ``background.py``). Three kinds of perturbation, each on or off:

- ``camera``: the camera's pose in a spherical box around its own (``camera_walk.py``);
- ``colour``: every material's RGB uniform within ``+- b`` of its own value (clipped to
  [0, 1]; geoms without a material and the skybox keep theirs); dynamic: a Gaussian step of
  ``0.03 b`` per channel per control step, clipped to the same box;
- ``background``: a video frame as the skybox texture (``iap_mjx.render.sky``), the floor
  (``grid`` material) partly transparent with the domain's alpha (reacher 0, cheetah and
  walker 1, the others 0.3). Each episode draws a video; static: one frame for the whole
  episode; dynamic: a random start frame and direction, one frame per control step,
  turning back at either end as the reference does.

The settings (tasks, difficulties, kinds, :class:`DistractionConfig`) are
``iap_mjx.configs.distraction``'s. Difficulty ``easy``/``medium``/``hard`` sets the scale ``b`` =
0.1/0.2/0.3 (and the number of videos). ``static``: each episode draws one perturbation and holds it;
``dynamic``: it moves once per control step, so ``action_repeat`` times per env step,
drawing its noise from a key kept with it. The perturbation lives in
``State.info["distraction"]`` (a :class:`Perturbation`), drawn at reset from the episode's
key (folded with a constant, so the physics' own draws are the undistracted env's); it
never touches the physics: :meth:`Distraction.scene` hands the camera a copy of the data
with ``cam_xpos``/``cam_xmat`` replaced, the geoms' colours and the sky texture.

Reference details kept: the camera walks once at reset (its first ``_apply``), colour and
background do not; the upper-quadrant limit and roll-free look-at for every domain but
reacher (axis-angle look-at there); the reference always reads the mode of camera 0, here
the mode of the camera rendered (the same camera in every suite task).
"""

from __future__ import annotations

import copy
import logging
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from iap_mjx.configs.distraction import DistractionConfig, check_task
from iap_mjx.envs import backgrounds as backgrounds_lib
from iap_mjx.envs import camera_walk
from iap_mjx.envs.base import Env, ModelEnv
from iap_mjx.render import sky as sky_lib

# distracting_control/suite_utils.get_background_kwargs: ground_plane_alpha
FLOOR_ALPHA = {"reacher": 0.0, "walker": 1.0, "cheetah": 1.0}
DEFAULT_FLOOR_ALPHA = 0.3
FLOOR_MATERIAL = "grid"
COLOUR_STEP = 0.03  # dynamic colour std per control step, times the scale
_FOLD = 0x0D15C  # folded into the episode key for the perturbation's own draws
logger = logging.getLogger(__name__)
_DEFAULT_RGBA = np.array([0.5, 0.5, 0.5, 1.0], np.float32)
_FIXED = int(mujoco.mjtCamLight.mjCAMLIGHT_FIXED)
_TRACKCOM = int(mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM)


def domain_name(env: Env) -> str:
    """The dm_control domain of a suite env (``cheetah``, ``ball_in_cup``, ...)."""
    name = getattr(env, "name", None)
    check_task(name)
    return str(name).split("-")[0]


def floor_alpha(domain: str) -> float:
    """The reference's ground-plane alpha for ``domain``."""
    return FLOOR_ALPHA.get(domain, DEFAULT_FLOOR_ALPHA)


def camera_model(env: ModelEnv, config: DistractionConfig) -> mujoco.MjModel:
    """The model the camera is built from: ``env.mj_model``, with the floor material's alpha
    set as the reference's background wrapper sets it (a copy; the physics' model is
    untouched)."""
    model = env.mj_model
    if "background" not in config.kinds:
        return model
    grid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MATERIAL, FLOOR_MATERIAL)
    if grid < 0:
        return model
    model = copy.copy(model)
    model.mat_rgba[grid, 3] = floor_alpha(domain_name(env))
    return model


class Perturbation(struct.PyTreeNode):
    """One episode's distraction state (``State.info["distraction"]``; a leading axis under
    ``vmap``). Fields of kinds that are off are ``None``.

    Attributes:
      key: the key of the dynamic walks' noise.
      camera: the ``camera_walk.CameraWalk``.
      colour: ``(M, 3)`` every material's RGB.
      video, frame, direction: ``()`` int32: the background video, its frame, and the
        dynamic step (+1 / -1; 0 when static).
    """

    key: jax.Array
    camera: Any = None
    colour: Any = None
    video: Any = None
    frame: Any = None
    direction: Any = None


class Distraction:
    """The perturbations of one pixel env: ``reset`` draws, ``advance`` walks, ``scene`` turns
    the state into what the camera draws.

    Args:
      env: the suite env (``mj_model``, ``name``, ``config.action_repeat``).
      camera: the ``iap_mjx.render.Camera`` that renders (built from :func:`camera_model`).
      config: the ``DistractionConfig``.
      videos: the background videos (``backgrounds.BackgroundVideos``) when the background
        kind is on.
    """

    def __init__(
        self,
        env: ModelEnv,
        camera: Any,
        config: DistractionConfig,
        videos: backgrounds_lib.BackgroundVideos | None = None,
    ):
        self.config = config
        self.domain = domain_name(env)
        model = env.mj_model
        self.camera_id = camera.config.camera_id
        self.control_steps = int(getattr(getattr(env, "config", None), "action_repeat", 1))
        self.kinds = config.kinds
        if "camera" in self.kinds:
            mode = int(model.cam_mode[self.camera_id])
            if mode not in (_FIXED, _TRACKCOM):
                raise ValueError(
                    f"{self.domain}: camera {self.camera_id} has mode {mode}; the camera "
                    "distraction supports fixed and trackcom cameras (as the reference)."
                )
            self.tracking = mode == _TRACKCOM
            self.walk_settings = camera_walk.WalkSettings.make(
                config.scale, config.dynamic, upper_quadrant=self.domain != "reacher"
            )
        if "colour" in self.kinds:
            original = np.asarray(model.mat_rgba[:, :3], np.float32)
            # distracting_control/suite_utils.get_color_kwargs: max_delta, step_std
            self.colour_delta = config.scale
            self.colour_step = COLOUR_STEP * config.scale if config.dynamic else 0.0
            self.colour_low = np.clip(original - self.colour_delta, 0.0, 1.0)
            self.colour_high = np.clip(original + self.colour_delta, 0.0, 1.0)
            # scene geoms whose colour is their material's (default rgba, as mjv draws them)
            materials = np.asarray(model.geom_matid[camera.geom_ids], np.int32)
            own = ~np.all(np.isclose(model.geom_rgba[camera.geom_ids], _DEFAULT_RGBA), axis=1)
            self.geom_material = np.where((materials >= 0) & ~own, materials, -1)
            self.geom_rgb = np.asarray(camera.scene.geom_rgb, np.float32)
        if "background" in self.kinds:
            if videos is None:
                raise ValueError("the background distraction needs its videos (backgrounds.load).")
            if videos.nbytes > (1 << 24) and not jax.config.values["jax_use_simplified_jaxpr_constants"]:
                logger.warning(
                    "the background videos (%.0f MB) will be embedded in every compiled program "
                    "(slow to compile); call iap_mjx.runtime.setup() (or hoist_large_constants()) "
                    "before importing jax",
                    videos.nbytes / 1e6,
                )
            # packed once (``sky.pack_rgb``): a frame is then one gather per pixel, no repacking
            self.frames = sky_lib.pack_rgb(jnp.asarray(videos.frames))  # (V, F, S * S) int32
            self.lengths = jnp.asarray(videos.lengths)
            self.num_videos = videos.num_videos

    # ---- per episode --------------------------------------------------------------------

    def reset(self, key: jax.Array, data: Any) -> Perturbation:
        """The episode's draw from ``key`` and the reset state's ``data`` (an ``mjx.Data``
        after kinematics): the reference's resets, with the camera's first walk."""
        key = jax.random.fold_in(key, _FOLD)
        key, k_camera, k_colour, k_video, k_frame, k_direction, k_walk = jax.random.split(key, 7)
        fields: dict[str, Any] = {}
        if "camera" in self.kinds:
            cam_pos, cam_mat, com = self._camera_now(data)
            start = camera_walk.start(k_camera, self.walk_settings, cam_pos, cam_mat, com, self.tracking)
            fields["camera"] = self._walk_camera(start, k_walk)
        if "colour" in self.kinds:
            fields["colour"] = jax.random.uniform(
                k_colour, self.colour_low.shape, minval=self.colour_low, maxval=self.colour_high
            )
        if "background" in self.kinds:
            video = jax.random.randint(k_video, (), 0, self.num_videos)
            fields["video"] = video
            fields["frame"] = jax.random.randint(k_frame, (), 0, self.lengths[video])
            fields["direction"] = (
                jnp.where(jax.random.bernoulli(k_direction), 1, -1).astype(jnp.int32)
                if self.config.dynamic
                else jnp.zeros((), jnp.int32)
            )
        return Perturbation(key=key, **fields)

    def advance(self, perturbation: Perturbation, control_steps: int | None = None) -> Perturbation:
        """``control_steps`` control steps (default: the env's action repeat) of the dynamic
        walks; static perturbations are returned as they are."""
        if not self.config.dynamic:
            return perturbation
        count = self.control_steps if control_steps is None else control_steps

        def one(p: Perturbation, _: Any) -> tuple[Perturbation, None]:
            key, k_camera, k_colour = jax.random.split(p.key, 3)
            p = p.replace(key=key)
            if "camera" in self.kinds:
                p = p.replace(camera=self._walk_camera(p.camera, k_camera))
            if "colour" in self.kinds:
                step = jax.random.normal(k_colour, self.colour_low.shape) * self.colour_step
                p = p.replace(colour=jnp.clip(p.colour + step, self.colour_low, self.colour_high))
            if "background" in self.kinds:
                frame, direction = p.frame + p.direction, p.direction
                direction = jnp.where(frame <= 0, jnp.abs(direction), direction)
                frame = jnp.maximum(frame, 0)
                length = self.lengths[p.video]
                past_end = frame >= length
                direction = jnp.where(past_end, -jnp.abs(direction), direction)
                frame = jnp.where(past_end, length - 1, frame)
                p = p.replace(frame=frame, direction=direction)
            return p, None

        return jax.lax.scan(one, perturbation, length=count)[0]

    def scene(self, data: Any, perturbation: Perturbation) -> tuple[Any, dict[str, Any]]:
        """What the camera draws: ``data`` with the perturbed camera pose written into
        ``cam_xpos``/``cam_xmat`` (a copy for rendering only), and the keyword arguments of
        ``Camera.render`` (``geom_rgb``, ``sky_texture``)."""
        inputs: dict[str, Any] = {}
        if "camera" in self.kinds:
            cam_pos, cam_mat, com = self._camera_now(data)
            position, rotation = camera_walk.pose(
                perturbation.camera, self.walk_settings, cam_pos, cam_mat, com, self.tracking
            )
            cam = self.camera_id
            data = data.replace(
                cam_xpos=data.cam_xpos.at[cam].set(position), cam_xmat=data.cam_xmat.at[cam].set(rotation)
            )
        if "colour" in self.kinds:
            picked = perturbation.colour[jnp.asarray(np.maximum(self.geom_material, 0))]
            inputs["geom_rgb"] = jnp.where(
                jnp.asarray(self.geom_material >= 0)[:, None], picked, jnp.asarray(self.geom_rgb)
            )
        if "background" in self.kinds:
            # the whole stack and the frame's row: the camera reads the frame in place
            stack = self.frames.reshape(-1, self.frames.shape[-1])
            inputs["sky_texture"] = (stack, perturbation.video * self.frames.shape[1] + perturbation.frame)
        return data, inputs

    # ---- helpers ------------------------------------------------------------------------

    def _camera_now(self, data: Any) -> tuple[jax.Array, jax.Array, jax.Array]:
        cam = self.camera_id
        return data.cam_xpos[cam], data.cam_xmat[cam], data.subtree_com[1]

    def _walk_camera(self, state: camera_walk.CameraWalk, key: jax.Array) -> camera_walk.CameraWalk:
        k_move, k_roll = jax.random.split(key)
        return camera_walk.walk(
            state, self.walk_settings, jax.random.normal(k_move, (3,)), jax.random.normal(k_roll, ())
        )
