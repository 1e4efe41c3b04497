"""Drawing a recorded episode's steps on the host (Pillow and NumPy): each observation
upscaled, the top-l patches the attention layer picked outlined in red (as the paper's Figures
9-10) and the return so far in a caption above it (:func:`annotate`); for an env with a scene
(:func:`iap_mjx.viz.recording.has_scene`), the annotated view inset in the scene's top-right
corner (:func:`inset`); and a strip's frames tiled into a grid (:func:`tile_grid`).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from iap_mjx.attention.patches import patch_corner
from iap_mjx.viz import recording

if TYPE_CHECKING:  # viz is handed envs and policies built: it imports neither package at load
    from iap_mjx.envs.base import Env
    from iap_mjx.policies.base import Policy

RED = (230, 30, 30)
WHITE = (255, 255, 255)
MARK_BELOW = 12  # pixels: a patch drawn smaller than this also gets a ring around it
MARK_RADIUS = 8  # pixels, the ring's outer radius
INSET_MARGIN = 8  # pixels between the inset view and the frame's edges
CAPTION_HEIGHT = 16  # pixels of the black band above a frame that holds its caption


def fit_inset(frame_shape: tuple[int, int], scale: int, scene_size: tuple[int, int]) -> tuple[int, tuple[int, int]]:
    """``(scale, scene size)`` that hold an observation of ``frame_shape`` ``(h, w)``, annotated
    (a ``CAPTION_HEIGHT`` caption on top), inside a scene frame with :func:`inset`'s margins: ``scale``
    lowered as far as 1 where the view would not fit ``scene_size``, and the scene enlarged
    where even that does not fit (a large first-person camera)."""
    (height, width), (scene_h, scene_w) = frame_shape, scene_size
    fits = min((scene_h - 2 * INSET_MARGIN - CAPTION_HEIGHT) // height, (scene_w - 2 * INSET_MARGIN) // width)
    scale = max(1, min(scale, fits))
    return scale, (
        max(scene_h, CAPTION_HEIGHT + height * scale + 2 * INSET_MARGIN),
        max(scene_w, width * scale + 2 * INSET_MARGIN),
    )


def inset(scene: np.ndarray, view: np.ndarray) -> np.ndarray:
    """Pastes ``view`` (an annotated observation, uint8) into ``scene``'s (uint8 ``(H, W, 3)``,
    changed in place and returned) top-right corner inside a 2-pixel white frame,
    ``INSET_MARGIN`` pixels from the edges; ``ValueError`` if it does not fit
    (:func:`fit_inset` chooses sizes that do)."""
    height, width = view.shape[:2]
    if height + 2 * INSET_MARGIN > scene.shape[0] or width + 2 * INSET_MARGIN > scene.shape[1]:
        raise ValueError(f"an inset of {view.shape[:2]} pixels does not fit a {scene.shape[:2]} frame")
    top, left = INSET_MARGIN, scene.shape[1] - INSET_MARGIN - width
    scene[top - 2 : top + height + 2, left - 2 : left + width + 2] = 255
    scene[top : top + height, left : left + width] = view
    return scene


def draw_steps(
    env: Env,
    policy: Policy,
    record: dict[str, Any],
    steps: np.ndarray,
    *,
    scale: int,
    numbered: bool,
    scene_size: tuple[int, int] = recording.SCENE_VIDEO_SIZE,
) -> Iterator[np.ndarray]:
    """Yields the drawn frames (uint8) of a record's ``steps``, each captioned (:func:`annotate`;
    ``numbered``: the step in the caption): a pixel env's observation at ``scale`` with its
    patches, inset in the scene rendered at ``scene_size`` where the record has one
    (:func:`~iap_mjx.viz.recording.has_scene`; :func:`fit_inset` adjusts both so that the view
    fits); a state env's scene alone at ``scene_size``. Scene frames are rendered
    ``recording.RENDER_CHUNK`` at a time (:func:`~iap_mjx.viz.recording.render_scene`) as
    they are drawn, so a whole episode is never held at once."""
    returns = recording.live_returns(record)
    layer = getattr(policy, "layer", None)
    indices = record.get("indices")
    views, scene = record.get("frames"), record.get("scene")
    if views is not None and scene is not None:
        scale, scene_size = fit_inset(views.shape[1:3], scale, scene_size)
    batch = min(recording.RENDER_CHUNK, len(steps))
    for start in range(0, len(steps), batch):
        chunk = steps[start : start + batch]
        scenes = None
        if scene is not None:
            scenes = recording.render_scene(
                env, {name: value[chunk] for name, value in scene.items()}, scene_size, batch=batch
            )
        for i, t in enumerate(chunk):
            step = int(t) if numbered else None
            if views is None:
                assert scenes is not None  # a state env's record has its scene
                yield annotate(scenes[i], None, None, float(returns[t]), scale=1, step=step)
                continue
            view = annotate(
                views[t], None if indices is None else indices[t], layer, float(returns[t]), scale=scale, step=step
            )
            yield view if scenes is None else inset(scenes[i], view)


def annotate(
    frame: np.ndarray,
    indices: np.ndarray | None,
    layer: Any,
    episode_return: float,
    *,
    scale: int = 3,
    step: int | None = None,
) -> np.ndarray:
    """``frame (H, W, 3)`` (floats in [0, 1], or uint8) -> ``(scale H + CAPTION_HEIGHT, scale W, 3)``
    uint8 with patches and text.

    Each selected patch is outlined in red, a white line just inside the red one (a red line
    alone vanishes on the quadruped course's red walls); one drawn smaller than ``MARK_BELOW``
    pixels (a 2x2 patch at 3x is 6 pixels) has no room inside and instead gets a 2-pixel red ring
    of radius ``MARK_RADIUS`` around its centre, inside a white ring, so that it can be seen at a
    glance on any background (a red ring alone vanishes on the suite's red retina photograph).
    """
    from PIL import Image, ImageDraw

    pixels = frame if frame.dtype == np.uint8 else (np.clip(frame, 0, 1) * 255).astype(np.uint8)
    image = Image.fromarray(pixels)
    image = image.resize((frame.shape[1] * scale, frame.shape[0] * scale), Image.Resampling.NEAREST)
    canvas = Image.new("RGB", (image.width, image.height + CAPTION_HEIGHT), (0, 0, 0))
    canvas.paste(image, (0, CAPTION_HEIGHT))
    draw = ImageDraw.Draw(canvas)
    if indices is not None and layer is not None:
        cols, stride = layer.grid[1], layer.config.effective_stride
        corners = [patch_corner(int(index), cols, stride) for index in indices]
        boxes = [(column * scale, CAPTION_HEIGHT + row * scale) for row, column in corners]
        size = layer.config.patch_size * scale
        if size >= MARK_BELOW:  # white lines inside the red ones, all drawn first: overlapping
            for left, top in boxes:  # patches (stride < patch) keep every red edge whole
                draw.rectangle([left + 1, top + 1, left + size - 2, top + size - 2], outline=WHITE)
        for left, top in boxes:
            draw.rectangle([left, top, left + size - 1, top + size - 1], outline=RED)
            if size < MARK_BELOW:
                x, y = left + size / 2, top + size / 2
                halo = MARK_RADIUS + 2
                draw.ellipse([x - halo, y - halo, x + halo, y + halo], outline=WHITE, width=2)
                draw.ellipse([x - MARK_RADIUS, y - MARK_RADIUS, x + MARK_RADIUS, y + MARK_RADIUS], outline=RED, width=2)
    caption = f"return {episode_return:8.2f}" if step is None else f"step {step}   return {episode_return:.2f}"
    draw.text((2, 2), caption, fill=(255, 255, 255))
    return np.asarray(canvas)


def tile_grid(tiles: list[np.ndarray], columns: int, gap: int = 4) -> np.ndarray:
    """``tiles`` (uint8 ``(H, W, 3)``, all one size) laid out ``columns`` to a row, in order,
    with white lines ``gap`` pixels wide between the tiles and between the rows; a last row
    that is short is filled with black tiles."""
    rows = [tiles[i : i + columns] for i in range(0, len(tiles), columns)]
    blank = np.zeros_like(tiles[0])
    between = np.full((tiles[0].shape[0], gap, 3), 255, np.uint8)
    lines = [
        np.concatenate([part for tile in row + [blank] * (columns - len(row)) for part in (tile, between)][:-1], axis=1)
        for row in rows
    ]
    rule = np.full((gap, lines[0].shape[1], 3), 255, np.uint8)
    return np.concatenate([part for line in lines for part in (line, rule)][:-1], axis=0)
