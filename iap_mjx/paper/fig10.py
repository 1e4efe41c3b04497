"""Reproducing the paper's Figure 10: what the quadruped's IAP high level looks at along an
episode, for a small and a large patch size.

For each trained ``quadruped-walls-iap`` run (by default Table 2's runs in ``out``: patch size 1,
stride 1, and the preset's own 4x4, :mod:`iap_mjx.paper.table2`), one episode of the centre of its
latest checkpoint (the final one once the run is finished) on a course not seen in training (the
episode of ``PRNGKey(EVAL_SEED)`` itself, as ``iap-mjx video --seed 2021`` draws it: none of the
tables' evaluation episodes, whose keys are split from that seed) is written as a PNG
strip: ``frames`` frames evenly spaced over the episode, each the course seen from the camera
that follows the robot with the first-person camera inset, scaled up, the patches the high level
selects in red (``iap_mjx.viz.video.episode_strip``; the high level is evaluated at every step,
though its command is taken only when the one held runs out, so a frame shows what it would
pick were it asked then).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

from iap_mjx import configs
from iap_mjx.checks import require_int
from iap_mjx.configs.training import EVAL_SEED
from iap_mjx.sections import reproduce_command, tracked_copy, write_results_section

if TYPE_CHECKING:  # check() builds them, importing iap_mjx.es lazily
    from iap_mjx.envs.base import Env
    from iap_mjx.policies.base import AttendingPolicy

logger = logging.getLogger(__name__)


def default_runs() -> tuple[str, str]:
    """The runs drawn by default: Table 2's smallest patches and the preset's
    (``table2.run_name``; imported here, as it loads JAX)."""
    from iap_mjx.paper import table2

    return table2.run_name((1, 1), 0), table2.run_name(None, 0)


def check(run_dirs: tuple[Path, ...]) -> dict[Path, tuple[configs.TrainConfig, Env, AttendingPolicy]]:
    """``{run_dir: (config, env, policy)}`` for runs with a checkpoint whose hierarchical policy
    selects patches of the camera (an IAP high level, eyes open), built and nothing compiled;
    ``ValueError`` naming the run otherwise."""
    from iap_mjx.es import checkpoint, make_env_and_policy
    from iap_mjx.es.results import trained_config
    from iap_mjx.policies.base import attends

    if not run_dirs or len(set(run_dirs)) != len(run_dirs):
        raise ValueError(f"fig10 needs distinct run directories, got {[str(run_dir) for run_dir in run_dirs]}")
    checked = {}
    for run_dir in run_dirs:
        if checkpoint.latest_step(run_dir) is None:
            raise ValueError(f"{run_dir}: no checkpoint (train it first)")
        config = trained_config(run_dir)  # as es.load_run reads it below
        env, policy = make_env_and_policy(config)
        if config.policy.kind != "hierarchical" or not attends(policy):
            raise ValueError(
                f"{run_dir}: its {config.policy.kind!r} policy selects no patches of the camera "
                "(fig10 shows a hierarchical policy's IAP high level with its eyes open, e.g. "
                "quadruped-walls-iap's, not -cnn's or -blind's)"
            )
        checked[run_dir] = (config, env, policy)
    return checked


def strip_name(policy: AttendingPolicy) -> str:
    """``fig10-p<patch size>-s<stride>.png`` of an attention policy."""
    attention = policy.layer.config
    return f"fig10-p{attention.patch_size}-s{attention.effective_stride}.png"


def draw_strip(run_dir: Path, env: Env, policy: AttendingPolicy, path: Path, *, frames: int) -> tuple[Path, float]:
    """The PNG strip at ``path`` of one episode of the run's latest centre (``env`` and
    ``policy``: :func:`check`'s, built once): the episode of ``PRNGKey(EVAL_SEED)``, ``frames``
    frames over it, the scene with the camera inset (``iap_mjx.viz.video.STRIP_SCENE_SCALE``x)
    and the selected patches in red; returns the path and the episode's return."""
    from iap_mjx import es
    from iap_mjx.viz import artifacts

    result = es.load_run(run_dir, env=env, policy=policy)  # the ones check built
    return artifacts.write_strip(result, path, seed=EVAL_SEED, frames=frames)


def reproduce_fig10(
    out_dir: str | Path,
    *,
    run_dirs: tuple[str | Path, ...] | None = None,
    frames: int = 6,
    results: str | Path | None = None,
) -> str:
    """Writes one strip per run (default: :func:`default_runs` in ``out_dir``) into ``out_dir``
    and returns markdown with each image and its caption; ``results``: a markdown file whose
    ``fig10`` section is rewritten with it."""
    from iap_mjx.viz import video

    require_int("frames", frames)
    out_dir = Path(out_dir)
    checked = check(tuple(Path(run_dir) for run_dir in (run_dirs or [out_dir / name for name in default_runs()])))
    names = [strip_name(policy) for _, _, policy in checked.values()]
    if len(set(names)) != len(names):
        raise ValueError(f"fig10: two runs of the same patch size and stride ({', '.join(names)})")
    out_dir.mkdir(parents=True, exist_ok=True)
    parts = []
    for (run_dir, (_, env, policy)), name in zip(checked.items(), names):
        path, episode_return = draw_strip(run_dir, env, policy, out_dir / name, frames=frames)
        attention = policy.layer.config
        parts.append(
            (
                path,
                f"Patch size {attention.patch_size}, stride {attention.effective_stride} "
                f"(L = {policy.layer.num_patches:,} patches, top {attention.top_l} selected): `{run_dir}`, "
                f"episode return {episode_return:.2f}.",
            )
        )
        logger.info("fig10: %s, return %.2f", path, episode_return)
    links = [path if results is None else tracked_copy(path, Path(results), "fig10") for path, _ in parts]
    markdown = "\n\n".join(f"{caption}\n\n![{path.stem}]({link})" for (path, caption), link in zip(parts, links))
    if results is not None:
        write_results(
            Path(results),
            markdown,
            run_dirs=tuple(checked),
            frames=frames,
            out_dir=out_dir,
            scale=video.STRIP_SCENE_SCALE,
        )
    return markdown


def write_results(
    path: Path, markdown: str, *, run_dirs: tuple[Path, ...], frames: int, out_dir: Path, scale: int
) -> None:
    """The ``fig10`` section of ``path``: the command and the strips (the camera inset at ``scale``x)."""
    command = reproduce_command(
        "fig10",
        ["--run-dirs " + ",".join(str(run_dir) for run_dir in run_dirs), f"--frames {frames}"],
        out=out_dir,
        results=path,
    )
    body = (
        f"## Figure 10: what the quadruped's IAP high level selects, small and large patches\n\n"
        f"Command: `{command}`. One episode of each run's latest centre on a course not seen in training "
        f"(`iap-mjx video --seed {EVAL_SEED}`'s episode); {frames} frames evenly spaced over it, each the course "
        f"from the camera that follows the robot, the first-person camera inset at {scale}x with the selected "
        "patches in red (the high level's choice were it asked at that step; it is asked when the command it "
        "holds runs out).\n\n"
        f"{markdown}\n"
    )
    write_results_section(path, "fig10", body)
