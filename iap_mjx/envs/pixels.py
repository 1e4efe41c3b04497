"""Pixel observations for any env: the ray-cast camera inside ``reset``/``step``.

``with_pixels(env, obs_mode=...)`` returns an env with the same protocol whose ``State.obs``
is an image rendered from ``State.data`` by ``iap_mjx.render.Camera``:

- ``"pixels"``: ``(H, W, 3 * frame_stack)`` float32 RGB in [0, 1];
- ``"pixels_depth"``: ``(H, W, 4 * frame_stack)`` RGB-D, depth in metres along the optical
  axis (the camera's far plane where nothing is hit);
- ``"pixels+state"``: ``{"pixels": (H, W, 3 * frame_stack), "state": (n,)}``;
- ``"depth+state"``: ``{"pixels": (H, W, frame_stack), "state": (n,)}``, the depth channel
  alone (the camera's geometry pass, no colour), scaled to ``[0, 1]``:
  ``min(depth, depth_max) / depth_max`` with depth in metres along the optical axis, so 1 is
  ``depth_max`` (default ``iap_mjx.configs.env.DEPTH_MAX``, 4 m) or farther, sky included. A
  network gets a bounded input whose scale does not depend on the scene's far plane.

Frames are stacked along channels, oldest first (the newest frame is the last ``C``
channels); at ``reset`` the first frame fills the whole stack.

With ``distraction`` (an ``iap_mjx.configs.distraction.DistractionConfig``) the frames are the
Distracting Control Suite's: the episode's perturbation is drawn at reset, kept in
``State.info["distraction"]``, advanced once per control step, and handed to the camera
(pose, colours, sky) without touching the physics.
"""

from __future__ import annotations

from typing import Any, Protocol, TypeGuard

import jax
import jax.numpy as jnp

from iap_mjx.checks import require_choice, require_int
from iap_mjx.configs.distraction import DistractionConfig
from iap_mjx.configs.env import DEPTH_MAX, PIXEL_MODES, check_depth_max
from iap_mjx.envs import distraction as distraction_lib
from iap_mjx.envs.base import ModelEnv, State
from iap_mjx.render import Camera


class GeomMapping(ModelEnv, Protocol):
    """An env whose frames come with the geom each pixel shows (:meth:`PixelEnv.geom_map`):
    what ``iap-mjx attended`` tallies the selected patches by."""

    def geom_map(self, data: Any, perturbation: Any = None) -> jax.Array: ...


def maps_geoms(env: object) -> TypeGuard[GeomMapping]:
    """Whether ``env`` has :class:`GeomMapping`'s ``geom_map`` and ``mj_model`` (``hasattr``,
    so that a wrapper forwarding attributes with ``__getattr__``, as :class:`PixelEnv`, counts)."""
    return hasattr(env, "geom_map") and hasattr(env, "mj_model")


class PixelEnv:
    """An env whose observations are camera images (see the module docstring).

    Everything not about observations (``mj_model``, ``mjx_model``, ``config``,
    ``action_size``, ``episode_length``, ``state_observation``, ...) is the wrapped env's.

    Args:
      env: an env with ``mj_model`` (``mujoco.MjModel``): :class:`iap_mjx.envs.base.ModelEnv`.
      obs_mode: ``"pixels"``, ``"pixels_depth"``, ``"pixels+state"`` or ``"depth+state"``.
      camera_id, height, width: the model camera and image size (default 100x100, camera 0,
        as the IAP paper's Cheetah-Run experiment).
      frame_stack: frames stacked along channels, oldest first.
      distraction: Distracting Control Suite perturbations (``None``: none); ``videos``
        the background videos they need (``iap_mjx.envs.backgrounds.load``).
      depth_max: ``"depth+state"`` only: metres of depth mapped onto ``[0, 1]`` (``None``:
        ``DEPTH_MAX``).
      camera_config: further ``iap_mjx.render.CameraConfig`` fields (shading, sky, ...).

    Attributes:
      env: the wrapped (state-observation) env.
      camera: the ``iap_mjx.render.Camera`` used.
      distraction: the ``distraction.Distraction`` applied before rendering, or ``None``.
      obs_mode, frame_stack: as given.
      depth_max: metres of depth mapped onto ``[0, 1]`` (``"depth+state"``), else ``None``.
    """

    def __init__(
        self,
        env: ModelEnv,
        obs_mode: str = "pixels",
        camera_id: int = 0,
        height: int = 100,
        width: int = 100,
        frame_stack: int = 1,
        distraction: DistractionConfig | None = None,
        videos: Any = None,
        depth_max: float | None = None,
        **camera_config: Any,
    ):
        require_choice("obs_mode", obs_mode, PIXEL_MODES)
        require_int("frame_stack", frame_stack)
        check_depth_max(depth_max, obs_mode)
        self.env = env
        self.obs_mode = obs_mode
        self.frame_stack = frame_stack
        self.depth_max = (DEPTH_MAX if depth_max is None else float(depth_max)) if obs_mode == "depth+state" else None
        model = env.mj_model if distraction is None else distraction_lib.camera_model(env, distraction)
        self.camera = Camera(model, camera_id=camera_id, height=height, width=width, **camera_config)
        self.distraction = (
            None if distraction is None else distraction_lib.Distraction(env, self.camera, distraction, videos)
        )

    def __getattr__(self, name: str) -> Any:
        if name == "env":  # not set yet (e.g. during unpickling): avoid recursion
            raise AttributeError(name)
        return getattr(self.env, name)

    @property
    def channels(self) -> int:
        """Channels of one frame: 4 for RGB-D, 1 for depth alone, else 3."""
        return {"pixels_depth": 4, "depth+state": 1}.get(self.obs_mode, 3)

    @property
    def with_state(self) -> bool:
        """Whether observations are ``{"pixels", "state"}`` dicts."""
        return self.obs_mode in ("pixels+state", "depth+state")

    @property
    def observation_shape(self) -> Any:
        cfg = self.camera.config
        pixels = (cfg.height, cfg.width, self.channels * self.frame_stack)
        if self.with_state:
            return {"pixels": pixels, "state": tuple(self.env.observation_shape)}
        return pixels

    def _scene(self, data: Any, perturbation: Any) -> tuple[Any, dict[str, Any]]:
        """``data`` and the camera's inputs as the episode's distraction draw sets them."""
        if self.distraction is None:
            return data, {}
        if perturbation is None:
            raise ValueError(
                "a distracted env renders with the episode's perturbation: "
                "render(state.data, state.info['distraction'])"
            )
        return self.distraction.scene(data, perturbation)

    def render(self, data: Any, perturbation: Any = None) -> jax.Array:
        """One frame ``(H, W, C)`` float32 of ``data`` (RGB, RGB-D for ``"pixels_depth"``, the
        scaled depth for ``"depth+state"``); a distracted env needs the episode's
        ``perturbation`` (``state.info["distraction"]``)."""
        data, inputs = self._scene(data, perturbation)
        if self.obs_mode == "depth+state":
            depth_max = self.depth_max
            assert depth_max is not None  # set for "depth+state"
            depth, _ = self.camera.trace(data)  # the geometry pass alone: no colour is shown
            return (jnp.minimum(depth, depth_max) / depth_max)[..., None]
        rgb, depth = self.camera.render(data, **inputs)
        if self.obs_mode == "pixels_depth":
            return jnp.concatenate([rgb, depth[..., None]], axis=-1)
        return rgb

    def geom_map(self, data: Any, perturbation: Any = None) -> jax.Array:
        """``(H, W)`` int32: the MuJoCo geom id (``env.mj_model``'s) seen at each pixel of
        :meth:`render`'s frame, ``-1`` where nothing is hit (sky or background picture)."""
        data, inputs = self._scene(data, perturbation)
        return self.camera.render_ids(data, **inputs)[2]

    def reset(self, key: jax.Array) -> State:
        """The wrapped env's first state with its frame as the observation (``observation_shape``;
        ``key`` also draws the episode's distraction)."""
        return self._first(self.env.reset(key), key)

    def reset_to(self, *args: Any, key: jax.Array | None = None, **kwargs: Any) -> State:
        """The wrapped env's ``reset_to`` with pixel observations (``key``: the episode's
        distraction draw, required when the env is distracted, so that episodes differ)."""
        if key is None:
            if self.distraction is not None:
                raise ValueError("a distracted env's reset_to needs key= (the episode's distraction draw).")
            key = jax.random.PRNGKey(0)
        reset_to = getattr(self.env, "reset_to", None)
        if reset_to is None:
            raise AttributeError(f"{type(self.env).__name__} has no reset_to to wrap")
        return self._first(reset_to(*args, **kwargs), key)

    def step(self, state: State, action: jax.Array) -> State:
        """The wrapped env's step, observed through the camera: the new frame is rendered from
        the new physics state (and the distraction advanced, where dynamic)."""
        stack = self._pixels(state.obs)
        next_state = self.env.step(state, action)
        perturbation = None
        if self.distraction is not None:
            before = state.info["distraction"]
            after = self.distraction.advance(before)
            # an ended episode's frame holds still, as its physics does (done is sticky)
            perturbation = (
                after
                if after is before
                else jax.tree.map(lambda old, new: jnp.where(state.done > 0, old, new), before, after)
            )
            next_state = next_state.replace(info={**next_state.info, "distraction": perturbation})
        frame = self.render(next_state.data, perturbation)
        stack = jnp.concatenate([stack[..., self.channels :], frame], axis=-1)
        return next_state.replace(obs=self._observation(stack, next_state.obs))

    def _first(self, state: State, key: jax.Array) -> State:
        perturbation = None
        if self.distraction is not None:
            perturbation = self.distraction.reset(key, state.data)
            state = state.replace(info={**state.info, "distraction": perturbation})
        frame = self.render(state.data, perturbation)
        stack = jnp.concatenate([frame] * self.frame_stack, axis=-1)
        return state.replace(obs=self._observation(stack, state.obs))

    def _observation(self, stack: jax.Array, state_obs: jax.Array) -> Any:
        if self.with_state:
            return {"pixels": stack, "state": state_obs}
        return stack

    def _pixels(self, obs: Any) -> jax.Array:
        return obs["pixels"] if self.with_state else obs


with_pixels = PixelEnv
"""``with_pixels(env, obs_mode=..., ...)``: ``env`` seen through the camera (:class:`PixelEnv`)."""
