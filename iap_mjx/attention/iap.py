"""Implicit Attention for Pixels: patches, patch scores and top-l patch selection.

An image ``(H, W, C)`` is cut into ``L`` patches of side ``p`` with stride ``s``; each
flattened patch (``c = p*p*C`` values, ordered ``(row, col, channel)``) gives a query
``q = x W_Q`` and a key ``k = x W_K`` of dimension ``d``. A patch's score is the column sum
of the attention matrix, ``s_j = sum_i K(q_i, k_j)`` (paper eq. 1 with ``r = 1``), and the
policy sees the ``l`` best-scoring patches (their centres, optionally their pixels).

- Brute force builds the ``L x L`` matrix: ``O(L^2)`` time and memory. With row
  normalisation it is Tang et al.'s AttentionAgent.
- IAP (eq. 3) computes ``(1^T phi(Q)) phi(K)^T``: ``O(L M)``, never building ``L x L``.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from iap_mjx.attention import features as ft

KERNELS = ("brute",) + ft.KINDS
SCALINGS = ("eq4", "eq5", "none")


def patch_grid(height: int, width: int, patch_size: int, stride: int) -> tuple[int, int]:
    """The ``(rows, cols)`` of the patch grid; raises ``ValueError`` if patches do not tile.

    Patches must cover the image exactly: ``(H - p)`` and ``(W - p)`` divisible by ``s``.
    """
    for name, value in (("patch_size", patch_size), ("stride", stride)):
        if not isinstance(value, (int, np.integer)) or value <= 0:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if patch_size > height or patch_size > width:
        raise ValueError(f"patch_size {patch_size} is larger than the image ({height} x {width})")
    bad = [f"{name} {size}" for name, size in (("height", height), ("width", width))
           if (size - patch_size) % stride]
    if bad:
        raise ValueError(
            f"patches of size {patch_size} with stride {stride} do not tile the image: "
            f"({', '.join(bad)} - patch_size) is not a multiple of the stride; "
            f"choose sizes with (size - patch_size) % stride == 0")
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


def extract_patches(image: jax.Array, patch_size: int,
                    stride: int | None = None) -> tuple[jax.Array, jax.Array]:
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


def brute_scores(queries: jax.Array, keys: jax.Array, *, row_normalize: bool = False) -> jax.Array:
    """Column sums of the explicit softmax attention matrix ``A = exp(Q K^T)``.

    Args:
      queries, keys: ``(L, d)``.
      row_normalize: divide each row of ``A`` by its sum first (AttentionAgent's softmax).

    Returns:
      ``(L,)`` scores. Without row normalisation they are scaled by ``exp(-max(Q K^T))`` to
      stay finite in float32 (one positive constant: rankings are unchanged).
    """
    logits = queries @ keys.T
    if row_normalize:
        # Column sums of the row-softmax as one matvec (1 / row sums) @ exp. XLA CPU's column
        # reduction of softmax(logits) is pathologically slow at some vmap batch sizes (at L=625,
        # batch 18: ~17x slower per image than batch 64), which made a weak baseline.
        unnormalised = jnp.exp(logits - jax.lax.stop_gradient(jnp.max(logits, axis=-1, keepdims=True)))
        return (1.0 / jnp.sum(unnormalised, axis=-1)) @ unnormalised
    return jnp.sum(jnp.exp(logits - jax.lax.stop_gradient(jnp.max(logits))), axis=0)


def linear_scores(query_features: jax.Array, key_features: jax.Array) -> jax.Array:
    """IAP scores ``(1^T Q') K'^T`` from ``(L, M)`` features, in ``O(L M)``: -> ``(L,)``."""
    return key_features @ jnp.sum(query_features, axis=0)


def _weighted_rows(weights: jax.Array, rows: jax.Array) -> jax.Array:
    """``sum_t weights[t] * rows[t]``: ``weights (n,)``, ``rows (n, L)`` -> ``(L,)``, unrolled.

    For the tiny ``n`` here (``d``, ``r``) a chain of scalar-times-row multiply-adds stays
    inside one elementwise loop, where a ``dot`` would be its own kernel on XLA CPU.
    """
    out = weights[0] * rows[0]
    for t in range(1, rows.shape[0]):
        out = out + weights[t] * rows[t]
    return out


def _token_parts(x: jax.Array, projections: ft.Projections):
    """Token-minor ``omega z`` ``(m, L)``, ``|z|^2 / 2`` ``(L,)`` and signs ``(r, L)`` of ``x (L, d)``."""
    xt = x.T
    omega, xi = projections.omega, projections.xi
    projected = jnp.stack([_weighted_rows(omega[j], xt) for j in range(omega.shape[0])])
    half_sq_norm = 0.5 * jnp.sum(xt * xt, axis=0)
    signs = jnp.stack([jnp.where(_weighted_rows(xi[s], xt) >= 0, 1.0, -1.0).astype(x.dtype)
                       for s in range(xi.shape[0])])
    return projected, half_sq_norm, signs


def _shift(projected: jax.Array, half_sq_norm: jax.Array, stabilize: bool) -> jax.Array:
    """One log-shift per set, as :func:`features.stabilizing_shift` for the hybrid map."""
    if not stabilize:
        return jnp.zeros((), projected.dtype)
    return jax.lax.stop_gradient(
        jnp.maximum(jnp.max(half_sq_norm), jnp.max(projected - half_sq_norm)))


def hybrid_scores(queries: jax.Array, keys: jax.Array, projections: ft.Projections, *,
                  stabilize: bool = True) -> jax.Array:
    """The hybrid kernel's linear scores without building the ``3m(r+1)`` features.

    Equal to ``linear_scores(feature_map("hybrid", Q, query), feature_map("hybrid", K, key))``
    (up to float rounding) but in ``O(L m r)`` with ``m + r`` transcendentals per token. With
    ``F = [T, E]`` a token's ``2m`` trigonometric and ``m`` positive features and ``S`` its
    ``r`` signs, one query-key term is ``(T_q.T_k (1 + S_q.S_k / r) + E_q.E_k (1 - S_q.S_k / r)) / 2``.
    Summed over queries this needs only ``G = F_Q^T [1, S_Q]`` (``3m x (1 + r)``, one product
    with inner dimension ``L``); each key's score is then ``F_k . (G' [1, S_k])`` with ``G'``
    the sign-and-``1/r``-weighted ``G``.

    Layout, for XLA's CPU backend: tokens are the minor axis (``(features, L)`` rows) and the
    tiny contractions (over ``d`` and ``r``) are unrolled multiply-adds, so each side is a
    couple of elementwise loops over ``L`` rather than ~20 small kernels; measured 2.4x
    faster than the feature-major layout at ``L = 2500`` (``BENCHMARKS.md``, attention).

    Args:
      queries, keys: ``(L, d)``.
      projections: hybrid projections (``omega (m, d)``, ``xi (r, d)``).
      stabilize: one log-shift per side, as in :func:`features.feature_map`.

    Returns:
      ``(L,)`` scores.
    """
    m, r = projections.omega.shape[0], projections.xi.shape[0]

    def features(x: jax.Array) -> tuple[list[jax.Array], jax.Array]:
        """``[sin, cos, positive]`` blocks ``(m, L)`` with magnitudes, and signs ``(r, L)``."""
        projected, half_sq_norm, signs = _token_parts(x, projections)
        shift = _shift(projected, half_sq_norm, stabilize)
        sin, cos = ft.sincos(projected)
        trig_scale = jnp.exp(half_sq_norm - shift)
        return [sin * trig_scale, cos * trig_scale, jnp.exp(projected - half_sq_norm - shift)], signs

    q_blocks, q_signs = features(queries)
    basis = jnp.concatenate([jnp.ones_like(q_signs[:1]), q_signs], axis=0)  # (1 + r, L)
    moments = jnp.concatenate(q_blocks, axis=0) @ basis.T  # (3m, 1 + r)
    weights = jnp.concatenate([jnp.ones(2 * m), -jnp.ones(m)]).astype(moments.dtype) / r
    constant, linear = moments[:, 0], moments[:, 1:] * weights[:, None]

    k_blocks, k_signs = features(keys)
    scores = jnp.zeros(keys.shape[:1], keys.dtype)
    for b, block in enumerate(k_blocks):
        for j in range(m):
            row = b * m + j
            scores = scores + block[j] * (constant[row] + _weighted_rows(linear[row], k_signs))
    return scores / (2.0 * m)


def top_l(scores: jax.Array, l: int) -> jax.Array:
    """Indices ``(l,)`` of the ``l`` largest scores, best first; ties go to the lower index."""
    return jax.lax.top_k(scores, l)[1]


@dataclasses.dataclass(frozen=True)
class AttentionConfig:
    """Static settings of one IAP attention layer (hashable: safe as a ``jit`` static arg).

    Attributes:
      patch_size: patch side ``p`` in pixels (1 = one pixel per patch).
      stride: step between patches; ``None`` means ``patch_size`` (no overlap).
      d_qk: query/key dimension ``d``.
      top_l: number of patches ``l`` passed on to the controller.
      kernel: ``"brute"`` (explicit softmax) or a feature map kind (:data:`features.KINDS`).
      m: random features (``exp``/``trig``/``hybrid``; sign features of ``angular``).
      r: sign features of ``hybrid``.
      orthogonal: block-orthogonal random projections (else iid Gaussian).
      scaling: ``"eq4"`` (``x = d^{-1/4} u``), ``"eq5"`` (``x = c u / |u|``) or ``"none"``.
      eq5_scale: the constant ``c`` of eq. 5.
      row_normalize: brute force only: softmax each row (Tang et al.'s AttentionAgent).
      use_bias: affine ``x W + b`` queries/keys instead of linear.
      redraw_projections: draw new random projections every episode instead of once.
    """

    patch_size: int = 4
    stride: int | None = None
    d_qk: int = 4
    top_l: int = 10
    kernel: str = "hybrid"
    m: int = 10
    r: int = 5
    orthogonal: bool = True
    scaling: str = "eq4"
    eq5_scale: float = 1.0
    row_normalize: bool = False
    use_bias: bool = False
    redraw_projections: bool = False

    def __post_init__(self):
        if self.kernel not in KERNELS:
            raise ValueError(f"unknown attention kernel {self.kernel!r}; valid kernels: {', '.join(KERNELS)}")
        if self.scaling not in SCALINGS:
            raise ValueError(f"unknown scaling {self.scaling!r}; valid scalings: {', '.join(SCALINGS)}")
        for name in ("patch_size", "d_qk", "top_l", "m", "r"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise ValueError(f"AttentionConfig.{name} must be a positive integer, got {value!r}")
        if self.stride is not None and (not isinstance(self.stride, int) or self.stride <= 0):
            raise ValueError(f"AttentionConfig.stride must be a positive integer or None, got {self.stride!r}")
        if not self.eq5_scale > 0:
            raise ValueError(f"AttentionConfig.eq5_scale must be positive, got {self.eq5_scale!r}")
        if self.row_normalize and self.kernel != "brute":
            raise ValueError("row_normalize applies to kernel='brute' only "
                             "(IAP scores are column sums of an unnormalised attention matrix)")

    @property
    def step(self) -> int:
        """The stride actually used."""
        return self.patch_size if self.stride is None else self.stride


@struct.dataclass
class AttentionParams:
    """Trainable parameters: ``w_q``, ``w_k`` ``(c, d)``; ``b_q``, ``b_k`` ``(d,)`` or ``None``."""

    w_q: jax.Array
    w_k: jax.Array
    b_q: jax.Array | None = None
    b_k: jax.Array | None = None


@struct.dataclass
class Selection:
    """The layer's output for one image.

    Attributes:
      indices: ``(l,)`` int32 patch indices, best first.
      centres: ``(l, 2)`` their normalised centres (row, col) in [0, 1].
      scores: ``(L,)`` every patch's score.
      patches: ``(l, p*p*C)`` the selected patches' pixels, or ``None`` if not asked for.
    """

    indices: jax.Array
    centres: jax.Array
    scores: jax.Array
    patches: jax.Array | None = None


@dataclasses.dataclass(frozen=True)
class IAPAttention:
    """An attention layer for images of one static shape; validated when constructed.

    Usage::

        layer = IAPAttention(AttentionConfig(patch_size=4, top_l=10), image_shape=(100, 100, 3))
        params = layer.init(key)                       # trainable
        projections = layer.draw_projections(key2)     # random, not trained
        selection = jax.vmap(layer, in_axes=(None, None, 0))(params, projections, images)
    """

    config: AttentionConfig
    image_shape: tuple[int, int, int]

    def __post_init__(self):
        if len(self.image_shape) != 3:
            raise ValueError(f"image_shape must be (H, W, C), got {self.image_shape!r}")
        height, width, _ = self.image_shape
        patch_grid(height, width, self.config.patch_size, self.config.step)
        if self.config.top_l > self.num_patches:
            raise ValueError(
                f"top_l = {self.config.top_l} exceeds the number of patches L = {self.num_patches} "
                f"({height}x{width} image, patch_size {self.config.patch_size}, stride {self.config.step})")

    @property
    def grid(self) -> tuple[int, int]:
        """Patch grid ``(rows, cols)``."""
        height, width, _ = self.image_shape
        return patch_grid(height, width, self.config.patch_size, self.config.step)

    @property
    def num_patches(self) -> int:
        """``L``."""
        rows, cols = self.grid
        return rows * cols

    @property
    def patch_dim(self) -> int:
        """``c = p*p*C``."""
        return self.config.patch_size**2 * self.image_shape[2]

    def init(self, key: jax.Array) -> AttentionParams:
        """Gaussian ``W_Q``, ``W_K`` with variance ``1/c``; zero biases if ``use_bias``."""
        q_key, k_key = jax.random.split(key)
        shape = (self.patch_dim, self.config.d_qk)
        scale = 1.0 / math.sqrt(self.patch_dim)
        bias = jnp.zeros((self.config.d_qk,)) if self.config.use_bias else None
        return AttentionParams(w_q=scale * jax.random.normal(q_key, shape),
                               w_k=scale * jax.random.normal(k_key, shape), b_q=bias, b_k=bias)

    def draw_projections(self, key: jax.Array) -> ft.Projections:
        """The kernel's random projections (empty for ``brute`` and ``relu``)."""
        cfg = self.config
        if cfg.kernel == "brute":
            return ft.Projections()
        return ft.draw_projections(key, cfg.kernel, m=cfg.m, d=cfg.d_qk, r=cfg.r,
                                   orthogonal=cfg.orthogonal)

    def queries_keys(self, params: AttentionParams, image: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``image (H, W, C)`` -> queries, keys ``(L, d)``, input scaling applied.

        Non-overlapping patches: a reshape and one ``(L, c) @ (c, 2d)`` product. Overlapping
        patches: one strided convolution with kernel ``[W_Q | W_K]`` reshaped to
        ``(p, p, C, 2d)``, the same numbers without materialising the overlapping patches
        (on XLA CPU the reshape path was 10x faster than the convolution where both apply).
        """
        cfg = self.config
        p, channels = cfg.patch_size, self.image_shape[2]
        weights = jnp.concatenate([params.w_q, params.w_k], axis=1)  # (c, 2d)
        if cfg.step == p:
            patches, _ = extract_patches(image.astype(weights.dtype), p, p)
            projected = patches @ weights
        else:
            projected = jax.lax.conv_general_dilated(
                image[None].astype(weights.dtype), weights.reshape(p, p, channels, -1),
                window_strides=(cfg.step, cfg.step), padding="VALID",
                dimension_numbers=("NHWC", "HWIO", "NHWC"))
            projected = projected.reshape(self.num_patches, 2 * cfg.d_qk)
        queries, keys = projected[:, : cfg.d_qk], projected[:, cfg.d_qk:]
        if params.b_q is not None:
            queries, keys = queries + params.b_q, keys + params.b_k
        return self.scale_inputs(queries), self.scale_inputs(keys)

    def scale_inputs(self, u: jax.Array) -> jax.Array:
        """Paper eq. 4 (``d^{-1/4} u``), eq. 5 (``c u / |u|``) or identity; ``(..., d)``."""
        cfg = self.config
        if cfg.scaling == "eq4":
            return u * cfg.d_qk ** -0.25
        if cfg.scaling == "eq5":
            norm = jnp.linalg.norm(u, axis=-1, keepdims=True)
            return cfg.eq5_scale * u / jnp.maximum(norm, 1e-12)
        return u

    def scores(self, params: AttentionParams, projections: ft.Projections,
               image: jax.Array) -> jax.Array:
        """Every patch's score ``(L,)`` for one image ``(H, W, C)``."""
        cfg = self.config
        queries, keys = self.queries_keys(params, image)
        if cfg.kernel == "brute":
            return brute_scores(queries, keys, row_normalize=cfg.row_normalize)
        if cfg.kernel == "hybrid":
            return hybrid_scores(queries, keys, projections, stabilize=True)
        q_features = ft.feature_map(cfg.kernel, queries, projections, role="query", stabilize=True)
        k_features = ft.feature_map(cfg.kernel, keys, projections, role="key", stabilize=True)
        return linear_scores(q_features, k_features)

    def __call__(self, params: AttentionParams, projections: ft.Projections, image: jax.Array,
                 *, with_patches: bool = False) -> Selection:
        """Scores all patches of ``image (H, W, C)`` and selects the top ``l``."""
        if image.shape != tuple(self.image_shape):
            raise ValueError(f"image of shape {image.shape} given to a layer built for {self.image_shape}")
        scores = self.scores(params, projections, image)
        indices = top_l(scores, self.config.top_l)
        centres = jnp.asarray(patch_centres(*self.image_shape[:2], self.config.patch_size,
                                            self.config.step))[indices]
        patches = self.selected_patches(image, indices) if with_patches else None
        return Selection(indices=indices, centres=centres, scores=scores, patches=patches)

    def selected_patches(self, image: jax.Array, indices: jax.Array) -> jax.Array:
        """Pixels of the patches ``indices (l,)`` of ``image`` -> ``(l, p*p*C)``."""
        p, step = self.config.patch_size, self.config.step
        _, cols = self.grid

        def one(index):
            corner = (index // cols * step, index % cols * step, 0)
            return jax.lax.dynamic_slice(image, corner, (p, p, self.image_shape[2])).reshape(-1)

        return jax.vmap(one)(indices)
