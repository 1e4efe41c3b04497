"""The env registry: ``make(name, **overrides)`` and ``names()``; ``check_spec``/``make_spec``
take a training config's :class:`~iap_mjx.configs.EnvSpec` (its name and overrides).

Each task class names its config class (``config_class``: ``EnvConfig`` for the dm_control
ports, ``QuadrupedConfig`` for the quadruped's tasks); a task's settings are validated against
its own class before any model is built.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from iap_mjx.configs.distraction import check_task
from iap_mjx.configs.env import EnvConfig
from iap_mjx.configs.training import EnvSpec
from iap_mjx.envs.dmc import DmControlEnv


def _task_classes() -> dict[str, type[DmControlEnv]]:
    from iap_mjx.envs.ball_in_cup import BallInCupCatch
    from iap_mjx.envs.cartpole import CartpoleSwingup
    from iap_mjx.envs.cheetah import CheetahRun
    from iap_mjx.envs.finger import FingerSpin
    from iap_mjx.envs.quadruped import QuadrupedFlat, QuadrupedWalls
    from iap_mjx.envs.quadruped_gates import QuadrupedGates
    from iap_mjx.envs.quadruped_turn import QuadrupedTurn
    from iap_mjx.envs.reacher import ReacherEasy
    from iap_mjx.envs.walker import WalkerWalk

    classes = [
        BallInCupCatch,
        CartpoleSwingup,
        CheetahRun,
        FingerSpin,
        QuadrupedFlat,
        QuadrupedGates,
        QuadrupedTurn,
        QuadrupedWalls,
        ReacherEasy,
        WalkerWalk,
    ]
    return {cls.name: cls for cls in classes}


def names() -> tuple[str, ...]:
    """The registered task names, sorted."""
    return tuple(sorted(_task_classes()))


def check(name: str, config: EnvConfig | None = None, **overrides: Any) -> EnvConfig:
    """The config (the task's ``config_class``, an ``EnvConfig``) that ``make(name, config,
    **overrides)`` would use, built without loading any model: cheap enough to run when a
    training config is constructed.

    Raises:
      ValueError: unknown ``name`` or override name (the message lists the task's valid ones),
        a ``config`` of another task's class, a bad override value, or a distraction on a
        task outside the Distracting Control Suite's six.
    """
    classes = _task_classes()
    if name not in classes:
        raise ValueError(f"Unknown env {name!r}; valid names: {', '.join(sorted(classes))}.")
    config_class = classes[name].config_class
    fields = {field.name for field in dataclasses.fields(config_class)}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise ValueError(f"Unknown env setting(s) {unknown} for {name!r}; valid: {sorted(fields)}.")
    config = config if config is not None else config_class()
    if type(config) is not config_class:
        raise ValueError(f"{name!r} takes a {config_class.__name__}, got a {type(config).__name__}.")
    config = dataclasses.replace(config, **overrides) if overrides else config
    if config.distraction is not None:
        check_task(name)
    return config


def episode_length(name: str, config: EnvConfig | None = None, **overrides: Any) -> int:
    """Env steps an episode of ``make(name, config, **overrides)`` lasts, without building it.

    Raises:
      ValueError: as :func:`check`.
    """
    config = check(name, config, **overrides)  # an unknown name: a ValueError listing the valid ones
    return _task_classes()[name].episode_length_for(config)


def make(name: str, config: EnvConfig | None = None, **overrides: Any) -> Any:
    """Builds the env ``name`` with ``config`` and/or ``EnvConfig`` field ``overrides``.

    For ``obs_mode`` other than ``"state"`` the env is wrapped by
    ``iap_mjx.envs.pixels.with_pixels`` with the config's camera settings (and the task's
    ``camera_options``, e.g. the quadruped's first-person camera drawing the world only) and,
    with ``distraction`` set (``"easy"``/``"medium"``/``"hard"``), the Distracting Control
    Suite's perturbations (their background videos loaded here, before anything compiles).

    Raises:
      ValueError: as :func:`check`.
    """
    config = check(name, config, **overrides)
    env = _task_classes()[name](config)
    if env.config.obs_mode == "state":
        return env
    from iap_mjx.envs.pixels import with_pixels

    cfg = env.config
    distraction = cfg.distraction_config()
    videos = None
    if distraction is not None and "background" in distraction.kinds:
        from iap_mjx.envs import backgrounds

        videos = backgrounds.load(
            distraction.difficulty,
            distraction.background_dir,
            distraction.background_size,
            distraction.background_frames,
            distraction.background_videos,
        )
    return with_pixels(
        env,
        obs_mode=cfg.obs_mode,
        camera_id=cfg.camera_id,
        height=cfg.height,
        width=cfg.width,
        frame_stack=cfg.frame_stack,
        distraction=distraction,
        videos=videos,
        depth_max=cfg.depth_max,
        **getattr(env, "camera_options", {}),
    )


def check_spec(spec: EnvSpec) -> EnvConfig:
    """:func:`check` of a training config's env (``config.env``)."""
    return check(spec.name, **dict(spec.overrides))


def make_spec(spec: EnvSpec) -> Any:
    """:func:`make` of a training config's env (``config.env``)."""
    return make(spec.name, **dict(spec.overrides))
