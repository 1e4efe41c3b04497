"""What a finished run leaves for a person: the reward curve PNG and an annotated episode video
(what a pixel agent saw; for a state agent, the env's own camera, made on request by
``iap-mjx video``)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import jax

from iap_mjx import envs, policies
from iap_mjx.viz import curves, video

logger = logging.getLogger(__name__)


def env_and_policy(config: Any) -> tuple[Any, Any]:
    """The env and policy a ``TrainConfig`` names (built again, as values)."""
    env = envs.make(config.env.name, **dict(config.env.overrides))
    policy = policies.make(config.policy.kind, env.observation_shape, env.action_size,
                           **dict(config.policy.options))
    return env, policy


has_pixels = video.has_pixels


def write_video(result: Any, path: str | Path, *, seed: int = 0, steps: int | None = None) -> tuple[Path, float]:
    """An episode of ``result``'s centre params on its env: a pixel env's frames with the
    patches outlined, or a state env rendered from its video camera."""
    if steps is not None and (not isinstance(steps, int) or steps < 1):
        raise ValueError(f"steps = {steps!r} must be None (the episode) or an int >= 1")
    env, policy = env_and_policy(result.config)
    steps = env.episode_length if steps is None else steps
    logger.info("rendering a %d-step episode of the trained policy to %s", steps, path)
    return video.episode_video(env, policy, result.params, path, key=jax.random.PRNGKey(seed),
                               steps=steps, policy_fn=result.policy_fn)


def write_run_artifacts(result: Any, run_dir: str | Path) -> list[Path]:
    """Writes ``reward_curve.png`` and, for pixel envs, ``episode.mp4`` into ``run_dir``."""
    run_dir = Path(run_dir)
    paths = [curves.plot_reward_curve(result.history, run_dir / "reward_curve.png",
                                      title=f"{result.config.env.name}: {result.config.policy.kind} policy")]
    env, _ = env_and_policy(result.config)
    if has_pixels(env):
        path, episode_return = write_video(result, run_dir / "episode.mp4")
        logger.info("episode video: return %.1f", episode_return)
        paths.append(path)
    return paths
