"""What a finished run leaves for a person: the reward curve PNG and an annotated episode video
(what a pixel agent saw; for a state agent, the env's own camera, made on request by
``iap-mjx video``).

Each writer takes a ``TrainResult`` and runs the env and policy it carries (the ones the run
was built with), so a video costs no second build of the env (nor, for the Distracting Control
Suite, a second load of its background videos)."""

from __future__ import annotations

import concurrent.futures
import logging
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax

from iap_mjx.checks import require_int
from iap_mjx.viz import curves, recording, video

if TYPE_CHECKING:  # viz is handed envs and policies built: it imports neither package at load
    from iap_mjx.envs.base import Env
    from iap_mjx.es.results import TrainResult
    from iap_mjx.policies.base import Policy

logger = logging.getLogger(__name__)


def write_episode_video(
    result: TrainResult, path: str | Path, *, seed: int = 0, steps: int | None = None, program: Any = None
) -> tuple[Path, float]:
    """An episode of ``result``'s centre params on its env: a pixel env's frames with the
    patches outlined, or a state env rendered from its video camera. ``program``: the episode
    compiled ahead (:func:`compile_video_in_background`) for these ``steps``."""
    require_int("steps", steps, none_ok=True)  # None: the whole episode
    env, policy = result.env, result.policy
    steps = env.episode_length if steps is None else steps
    logger.info("rendering a %d-step episode of the trained policy to %s", steps, path)
    return video.episode_video(
        env,
        policy,
        result.params,
        path,
        key=jax.random.PRNGKey(seed),
        steps=steps,
        obs_stats=result.obs_stats,
        program=program,
    )


def write_strip(result: TrainResult, path: str | Path, *, seed: int = 0, frames: int = 6) -> tuple[Path, float]:
    """A PNG strip of ``frames`` frames from one episode of ``result``'s centre params, the
    selected patches drawn (:func:`video.episode_strip`)."""
    env, policy = result.env, result.policy
    if not recording.has_pixels(env):
        raise ValueError(f"{result.config.env.name!r} observes the state: a strip shows a pixel agent's frames")
    return video.episode_strip(
        env,
        policy,
        result.params,
        path,
        key=jax.random.PRNGKey(seed),
        steps=env.episode_length,
        frames=frames,
        obs_stats=result.obs_stats,
    )


def compile_video_in_background(env: Env, policy: Policy) -> concurrent.futures.Future | None:
    """Starts compiling the episode video :func:`write_run_artifacts` will render of ``policy``
    on ``env`` (the ones the run trains), in a daemon thread, and returns its future (``None``
    for a state env: a run writes no video of one).

    Called before training, the video's compile runs beside the ES iteration's (XLA compiles
    on one core, and a machine has more), so the video at the end of a run costs its
    rollout and encoding only (and, for an env with a scene, the scene renderer, compiled when
    the episode's length is known: ``drawing.draw_steps``). A daemon thread, which the process
    must not exit beside while it compiles (XLA aborts it): a command that stops early waits for
    the future first (``iap_mjx.cli.commands``).
    """
    if not recording.has_pixels(env):
        return None
    future: concurrent.futures.Future = concurrent.futures.Future()

    def work() -> None:
        try:
            future.set_result(recording.compile_episode_program(env, policy, steps=env.episode_length))
        except Exception as error:  # handed to whoever waits for the program
            future.set_exception(error)

    threading.Thread(target=work, name="compile-video", daemon=True).start()
    return future


def write_run_artifacts(
    result: TrainResult, run_dir: str | Path, video_program: concurrent.futures.Future | None = None
) -> list[Path]:
    """Writes ``reward_curve.png`` and, for pixel envs, ``episode.mp4`` into ``run_dir``;
    ``video_program`` is :func:`compile_video_in_background`'s future for this config."""
    run_dir = Path(run_dir)
    paths = [
        curves.plot_reward_curve(
            result.history,
            run_dir / "reward_curve.png",
            title=f"{result.config.env.name}: {result.config.policy.kind} policy",
        )
    ]
    if recording.has_pixels(result.env):
        program = video_program.result() if video_program is not None else None
        path, episode_return = write_episode_video(result, run_dir / "episode.mp4", program=program)
        logger.info("episode video: return %.1f", episode_return)
        paths.append(path)
    return paths
