"""Image patches: the patch grid, the patches' centres and corners, and the flattened patches.

An image ``(H, W, C)`` is cut into ``L`` patches of side ``p`` with stride ``s``, row-major
over the patch grid; each patch is flattened in ``(row, col, channel)`` order, ``c = p*p*C``
values.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from iap_mjx.checks import require_int


def patch_grid(height: int, width: int, patch_size: int, stride: int) -> tuple[int, int]:
    """The ``(rows, cols)`` of the patch grid; raises ``ValueError`` if patches do not tile.

    Patches must cover the image exactly: ``(H - p)`` and ``(W - p)`` divisible by ``s``.
    """
    for name, value in (("patch_size", patch_size), ("stride", stride)):
        # numpy's integers pass: the grid is computed from arrays' shapes too
        require_int(name, int(value) if isinstance(value, np.integer) else value)
    if patch_size > height or patch_size > width:
        raise ValueError(
            f"patch_size must be at most the image's height and width ({height} x {width}), got {patch_size}."
        )
    bad = [f"{name} {size}" for name, size in (("height", height), ("width", width)) if (size - patch_size) % stride]
    if bad:
        raise ValueError(
            f"patches of size {patch_size} with stride {stride} do not tile the image: "
            f"({', '.join(bad)} - patch_size) is not a multiple of the stride; "
            f"choose sizes with (size - patch_size) % stride == 0"
        )
    return (height - patch_size) // stride + 1, (width - patch_size) // stride + 1


def patch_centres(height: int, width: int, patch_size: int, stride: int) -> np.ndarray:
    """``(L, 2)`` patch centres ``(row, col)`` in row-major patch order, normalised to [0, 1].

    Pixel ``k`` spans ``[k, k+1)``, so the centre of a patch starting at pixel ``i`` is
    ``(i + p/2) / size``: 0 is the top/left edge of the image, 1 the bottom/right.
    """
    rows, cols = patch_grid(height, width, patch_size, stride)
    row_centres = (np.arange(rows) * stride + patch_size / 2) / height
    col_centres = (np.arange(cols) * stride + patch_size / 2) / width
    grid = np.stack(np.meshgrid(row_centres, col_centres, indexing="ij"), axis=-1)
    return grid.reshape(rows * cols, 2).astype(np.float32)


def patch_corner(index: Any, cols: int, stride: int) -> tuple[Any, Any]:
    """The top-left pixel ``(row, column)`` of patch ``index`` in a grid of ``cols`` patches per
    row (row-major order) at ``stride``; ``index`` an int or an integer array (NumPy or JAX),
    the result alike."""
    return index // cols * stride, index % cols * stride


def extract_patches(image: jax.Array, patch_size: int, stride: int | None = None) -> tuple[jax.Array, jax.Array]:
    """Cuts ``image (H, W, C)`` into flattened patches.

    Returns:
      patches: ``(L, p*p*C)``, row-major over the patch grid, each patch flattened in
        ``(row, col, channel)`` order (``image[i:i+p, j:j+p].reshape(-1)``).
      centres: ``(L, 2)`` normalised patch centres (see :func:`patch_centres`).
    """
    stride = patch_size if stride is None else stride
    height, width, channels = image.shape
    rows, cols = patch_grid(height, width, patch_size, stride)
    centres = jnp.asarray(patch_centres(height, width, patch_size, stride))
    if stride == patch_size:
        tiles = image[: rows * patch_size, : cols * patch_size]
        tiles = tiles.reshape(rows, patch_size, cols, patch_size, channels).swapaxes(1, 2)
        return tiles.reshape(rows * cols, patch_size * patch_size * channels), centres
    offsets = np.arange(patch_size)
    row_index = (np.arange(rows) * stride)[:, None, None, None] + offsets[None, None, :, None]
    col_index = (np.arange(cols) * stride)[None, :, None, None] + offsets[None, None, None, :]
    tiles = image[row_index, col_index]  # (rows, cols, p, p, C)
    return tiles.reshape(rows * cols, patch_size * patch_size * channels), centres
