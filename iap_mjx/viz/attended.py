"""What a pixel agent's attention looks at: the share of its selected patches' pixels that show
each geom of the scene (the agent's bodies, the floor, ...) or the background (sky or a
distraction picture), over whole episodes.

The geom seen at every pixel comes from the same ray trace as the frame
(``PixelEnv.geom_map``, the camera's ``render_ids``), recorded beside the selected patches
by the video's episode program (``recording.episode_program``'s ``extra``), so the shares
describe exactly the frames the policy saw.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import jax
import mujoco
import numpy as np

from iap_mjx.attention.patches import patch_corner
from iap_mjx.checks import require_int
from iap_mjx.viz import recording

if TYPE_CHECKING:  # viz is handed envs and policies built: it imports neither package at load
    from iap_mjx.envs.base import Env
    from iap_mjx.envs.pixels import GeomMapping
    from iap_mjx.policies.base import Policy

BACKGROUND = "background"


def geom_label(model: mujoco.MjModel, geom: int) -> str:
    """A geom's name, else its body's name and index, ``BACKGROUND`` for ``-1``."""
    if geom < 0:
        return BACKGROUND
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geom)
    if name:
        return name
    body = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(model.geom_bodyid[geom])) or "world"
    return f"{body} geom {geom}"


def patch_pixels(layer: Any, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns ``(..., p * p)`` of the pixels of patches ``indices (...)``."""
    patch = layer.config.patch_size
    top, left = patch_corner(indices, layer.grid[1], layer.config.effective_stride)
    offsets = np.arange(patch)
    rows = top[..., None, None] + offsets[:, None]
    columns = left[..., None, None] + offsets[None, :]
    rows, columns = np.broadcast_arrays(rows, columns)
    shape = indices.shape + (patch * patch,)
    return rows.reshape(shape), columns.reshape(shape)


def count_geoms(geoms: np.ndarray, indices: np.ndarray, layer: Any) -> dict[int, int]:
    """``{geom id: selected pixels showing it}`` from ``geoms (T, H, W)`` and ``indices (T, l)``."""
    rows, columns = patch_pixels(layer, indices)
    steps = np.arange(geoms.shape[0])[:, None, None]
    seen = geoms[steps, rows, columns]
    ids, counts = np.unique(seen, return_counts=True)
    return {int(i): int(c) for i, c in zip(ids, counts)}


def geom_episode_program(env: GeomMapping, policy: Policy, *, steps: int) -> Any:
    """The video's episode program recording also ``"geoms" (T, H, W)``: the geom map of
    each frame the policy sees."""

    def geom_map(state):
        return {"geoms": env.geom_map(state.data, state.info.get("distraction"))}

    return recording.episode_program(env, policy, steps=steps, extra=geom_map, scene=False)


def episode_counts(
    env: Env,
    policy: Policy,
    params: Any,
    *,
    episodes: int = 3,
    seed: int = 0,
    steps: int | None = None,
    obs_stats: Any = None,
    program: Any = None,
) -> list[dict[str, int]]:
    """Per episode, ``{label: selected pixels showing it}`` over the steps taken while each
    episode lived (a fallen quadruped's view of the ground after its episode ended is not
    counted) of ``episodes`` episodes of
    ``policy`` (an attention policy) on the pixel env ``env``, episode ``i`` from key
    ``split(PRNGKey(seed), episodes)[i]``. ``program``: :func:`geom_episode_program` for these
    ``steps`` (default: built here)."""
    from iap_mjx.envs.pixels import maps_geoms
    from iap_mjx.policies.base import attends

    if not (recording.has_pixels(env) and maps_geoms(env) and attends(policy)):
        raise ValueError("attended shares need an attention policy on a pixel env")
    require_int("episodes", episodes)
    steps = env.episode_length if steps is None else steps
    program = geom_episode_program(env, policy, steps=steps) if program is None else program
    out = []
    for key in jax.random.split(jax.random.PRNGKey(seed), episodes):
        record = recording.record_episode(env, policy, params, key, steps=steps, obs_stats=obs_stats, program=program)
        counts: dict[str, int] = {}
        alive = record["alive"]  # the frames the policy saw while its episode lived
        for geom, count in count_geoms(record["geoms"][alive], record["indices"][alive], policy.layer).items():
            label = geom_label(env.mj_model, geom)
            counts[label] = counts.get(label, 0) + count
        out.append(counts)
    return out


def shares(counts: list[dict[str, int]]) -> dict[str, float]:
    """``{label: share}`` of all episodes' selected pixels; shares sum to 1, largest first."""
    totals: dict[str, int] = {}
    for episode in counts:
        for label, count in episode.items():
            totals[label] = totals.get(label, 0) + count
    total = sum(totals.values())
    return {label: count / total for label, count in sorted(totals.items(), key=lambda item: -item[1])}


def markdown(counts: list[dict[str, int]]) -> str:
    """A markdown table of the shares over all episodes, and per label the episodes in which
    it has the largest share."""
    first = [max(episode, key=lambda label: episode[label]) for episode in counts]
    lines = ["| what the selected pixels show | share | episodes where it is the largest share |", "|---|---:|---:|"]
    lines += [
        f"| {label} | {100 * share:.1f}% | {first.count(label)} of {len(counts)} |"
        for label, share in shares(counts).items()
    ]
    return "\n".join(lines)
