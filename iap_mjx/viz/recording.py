"""The compiled side of an episode video: one episode run by JAX that records what a video
draws, and the scene camera's frames rendered afterwards from the poses it recorded.

One episode runs compiled (``lax.scan``, :func:`episode_program`) and records, at each step, a
pixel env's newest frame, the top-l patches the attention layer picked, the reward and, where a
scene is shown, the scene camera's poses. A state env has no image in its observations, so it
is shown by the ray-cast camera from its ``video_camera_id`` (a model camera, e.g. the
quadruped's trunk-tracking one; default camera 0) at ``STATE_VIDEO_SIZE``. A pixel env that
names a ``video_camera_id`` (the quadruped's courses, whose observation is the robot's own small
camera) is shown from that camera at ``SCENE_VIDEO_SIZE``, the robot's view inset in it. Such a
scene is not rendered inside the episode: the episode records the scene camera's poses at each
step, and the host renders the steps it draws from them (:func:`render_scene`), a chunk at a
time.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from iap_mjx.compiling import lower_afresh

if TYPE_CHECKING:  # viz is handed envs and policies built: it imports neither package at load
    from iap_mjx.envs.base import Env
    from iap_mjx.policies.base import Policy
    from iap_mjx.render import Camera

STATE_VIDEO_SIZE = (240, 320)  # (height, width) of frames rendered for state envs
SCENE_VIDEO_SIZE = (360, 480)  # (height, width) of the scene around a pixel env's inset view
RENDER_CHUNK = 50  # scene frames rendered per call: a bounded batch, one compiled shape


def newest_rgb(obs: Any, channels_per_frame: int) -> jax.Array:
    """The newest RGB frame ``(H, W, 3)`` of a (frame-stacked) pixel observation; a depth-only
    frame (one channel, ``"depth+state"``, in [0, 1]) is shown as grey, near dark."""
    pixels = obs["pixels"] if isinstance(obs, dict) else obs
    newest = pixels[..., pixels.shape[-1] - channels_per_frame :][..., :3]
    return jnp.repeat(newest, 3, axis=-1) if channels_per_frame == 1 else newest


def has_pixels(env: Env) -> bool:
    """Whether ``env`` observes pixels (else a video renders the env's own camera)."""
    return getattr(env, "obs_mode", "state") != "state"


def has_scene(env: Env) -> bool:
    """Whether ``env`` observes pixels and names a camera to show its scene from
    (``video_camera_id``): its videos show that scene with the observed view inset."""
    return has_pixels(env) and hasattr(env, "video_camera_id")


def state_camera(env: Env, size: tuple[int, int] = STATE_VIDEO_SIZE) -> Camera:
    """The ray-cast camera a video of a state env is rendered with: the model camera
    ``env.video_camera_id`` (default 0) of ``env.mj_model`` (:class:`~iap_mjx.envs.base.ModelEnv`),
    every geom group drawn."""
    from iap_mjx.render import Camera

    model = getattr(env, "mj_model", None)
    if model is None or model.ncam == 0:
        raise ValueError(
            f"{getattr(env, 'name', env)!r} observes the state and has no model camera to render a video from"
        )
    return Camera(model, camera_id=int(getattr(env, "video_camera_id", 0)), height=size[0], width=size[1])


def episode_program(
    env: Env, policy: Policy, *, steps: int, extra: Callable[[Any], dict] | None = None, scene: bool = True
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
      policy: the policy; if it selects patches (``policies.base.attends``: ``select`` and
        ``layer``, IAP) and the env has pixels, the selected patches are recorded.
      steps: env steps (actions) to record.
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
    from iap_mjx.policies.base import attends

    selector = policy if pixels and attends(policy) else None
    # a state env's only picture is its scene; the poses do not depend on the size drawn
    scene_camera = state_camera(env) if not pixels or (scene and has_scene(env)) else None

    @jax.jit
    def program(params, obs_stats, key):
        def record(step: Step) -> dict:
            kept = dict(extra(step.state)) if extra is not None else {}
            if pixels:
                kept["frames"] = newest_rgb(step.state.obs, channels)
            if selector is not None:
                kept["indices"] = selector.select(params, step.seen, step.policy_state).indices
            if scene_camera is not None:
                kept["scene"] = scene_camera.poses(step.state.data)
            kept["rewards"] = step.next_state.reward
            return kept

        return run_episode(env, policy, params, key, obs_stats, steps=steps, record=record).records

    return program


def compile_episode_program(env: Env, policy: Policy, *, steps: int, obs_stats: Any = None) -> Any:
    """:func:`episode_program` compiled ahead of time for ``policy``'s params shapes (and
    ``obs_stats``'s, if given): pass it to :func:`record_episode` as ``program``. Safe to call
    from a background thread while something else compiles or trains."""
    params = jax.eval_shape(policy.init, jax.random.PRNGKey(0))
    stats = None if obs_stats is None else jax.eval_shape(lambda: obs_stats)
    return lower_afresh(episode_program(env, policy, steps=steps), params, stats, jax.random.PRNGKey(0)).compile()


def record_episode(
    env: Env, policy: Policy, params: Any, key: jax.Array, *, steps: int, obs_stats: Any = None, program: Any = None
) -> dict[str, Any]:
    """Rolls one episode of ``steps`` env steps (actions) and records what a video needs.

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
        program = compile_episode_program(env, policy, steps=steps, obs_stats=obs_stats)
    record = jax.tree_util.tree_map(np.asarray, program(params, obs_stats, key))
    return {**record, "alive": record["alive"] > 0}


def last_live_step(record: dict[str, np.ndarray]) -> int:
    """The index of a recorded episode's last live step (the one that ends it, or the last)."""
    return int(np.flatnonzero(record["alive"])[-1])


def live_returns(record: dict[str, np.ndarray]) -> np.ndarray:
    """``(T,)`` the return so far at each step, counting live steps' rewards only."""
    return np.cumsum(np.where(record["alive"], record["rewards"], 0.0))


@functools.lru_cache(maxsize=4)
def _scene_renderer(camera: Camera) -> Callable[[dict[str, np.ndarray]], jax.Array]:
    """The jitted batched render of a scene camera's poses (the keys of
    :class:`~iap_mjx.render.tracing.Poses`, each array with a leading batch axis ``(N, ...)``)
    -> ``(N, H, W, 3)`` float32 frames, built once per camera (cameras are hashable), so that
    every video and strip of one env shares its compiled programs."""
    return jax.jit(jax.vmap(lambda pose: camera.render_poses(pose)[0]))


def render_scene(
    env: Env, poses: dict[str, np.ndarray], size: tuple[int, int] = SCENE_VIDEO_SIZE, *, batch: int | None = None
) -> np.ndarray:
    """``(N, H, W, 3)`` uint8: the scene camera's (:func:`state_camera`, ``size``) frames of
    ``N`` recorded steps' poses (a record's ``"scene"`` at those steps: the keys of
    :class:`~iap_mjx.render.tracing.Poses`, each a numpy array with a leading ``(N,)`` axis),
    rendered ``batch`` at a time (default ``min(RENDER_CHUNK, N)``), the last batch padded: one
    compiled shape."""
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
