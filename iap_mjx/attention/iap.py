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

from iap_mjx import chunks
from iap_mjx.attention import features as ft

KERNELS = ("brute",) + ft.KINDS
SCALINGS = ("eq4", "eq5", "none")
ROW_KERNELS = ("relu", "hybrid")  # scored from token rows (tokens minor), in chunks under vmap
# Patches scored together under vmap (batch_chunk=None). Development runs at L = 19,200 (2 XLA
# devices, batch 64 in groups of 4 as in benchmarks/attention.py; same process): chunks of 2 images
# took 0.66x the CPU time per image of the previous scoring code, chunks of 3 0.87x, chunks of 4
# 0.79x.
CHUNK_TOKENS = 40_000


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


def _rows(matrix: jax.Array, x: jax.Array) -> jax.Array:
    """``matrix (n, d)`` times token rows ``x (..., d, L)`` -> ``(..., n, L)``, as ``d``
    broadcast multiply-adds (one elementwise loop on XLA CPU, where a dot with inner
    dimension ``d = 4`` would be its own kernel and a materialised buffer)."""
    out = matrix[:, 0, None] * x[..., 0:1, :]
    for e in range(1, x.shape[-2]):
        out = out + matrix[:, e, None] * x[..., e:e + 1, :]
    return out


def _half_sq_norm(x: jax.Array) -> jax.Array:
    """``|x|^2 / 2`` of token rows ``x (..., d, L)`` -> ``(..., 1, L)``."""
    out = x[..., 0:1, :] * x[..., 0:1, :]
    for e in range(1, x.shape[-2]):
        out = out + x[..., e:e + 1, :] * x[..., e:e + 1, :]
    return 0.5 * out


def _larger(a: jax.Array, b: jax.Array) -> jax.Array:
    """``max(a, b)`` elementwise as compare-and-select (the same number for non-NaN inputs).

    With ``jnp.maximum`` XLA's CPU backend (jax 0.10) hands the maxima of :func:`_row_max` to a
    YNNPACK elementwise kernel and first copies each of its rows out: at ``L = 19,200`` that was
    13% of the hybrid layer's CPU time (profile of ``benchmarks/attention.py``'s batch 64); a
    select stays in XLA's own loop, fused with the rows' computation. A NaN in ``b`` is kept
    and one in ``a`` dropped; a NaN query or key makes its ``|x|^2/2`` NaN, which the shift's
    maximum over tokens propagates either way."""
    return jnp.where(a > b, a, b)


def _row_max(x: jax.Array) -> jax.Array:
    """Maximum over the rows of ``x (..., n, L)`` -> ``(..., 1, L)``, as one elementwise loop."""
    out = x[..., 0:1, :]
    for i in range(1, x.shape[-2]):
        out = _larger(x[..., i:i + 1, :], out)
    return out


def _hybrid_shift(half_sq_norm: jax.Array, projected: jax.Array, stabilize: bool) -> jax.Array:
    """The log-shift of one set, as :func:`features.stabilizing_shift` for the hybrid map:
    ``max(max_t |x_t|^2/2, max_{t,j} omega_j x_t - |x_t|^2/2)``, ``(..., 1, 1)`` (or 0).

    Args:
      half_sq_norm: ``(..., 1, L)`` ``|x_t|^2 / 2``.
      projected: ``(..., m, L)`` ``omega x_t``.

    The per-token maximum over ``j`` is taken before subtracting ``|x|^2/2`` (the same
    number: rounding is monotone), so only one row per set goes to the reduction over ``L``."""
    if not stabilize:
        return jnp.zeros((), half_sq_norm.dtype)
    per_token = _larger(_row_max(projected) - half_sq_norm, half_sq_norm)
    return jax.lax.stop_gradient(jnp.max(per_token, axis=-1, keepdims=True))


def _sign_rows(x: jax.Array, xi: jax.Array) -> list[jax.Array]:
    """``sgn(xi_s x)`` of token rows ``x (..., d, L)``: ``r`` rows ``(..., 1, L)`` in ``{-1, +1}`` (0 maps to +1)."""
    return [jnp.where(_rows(xi[s:s + 1], x) >= 0, 1.0, -1.0).astype(x.dtype) for s in range(xi.shape[0])]


def _query_moments(queries: jax.Array, projections: ft.Projections, stabilize: bool) -> jax.Array:
    """``F_Q^T [1, S_Q]`` ``(..., 3m, 1 + r)``: the features ``F = [e sin(omega q); e cos(omega q);
    exp(omega q - |q|^2/2 - shift)]`` (``e = exp(|q|^2/2 - shift)``, ``(..., 3m, L)``) summed over
    the queries against ``[1; signs]``, one product with inner dimension ``L``."""
    omega, xi = projections.omega, projections.xi
    half_sq_norm = _half_sq_norm(queries)
    projected = _rows(omega, queries)
    shift = _hybrid_shift(half_sq_norm, projected, stabilize)
    sin, cos = ft.sincos(projected)
    trig_scale = jnp.exp(half_sq_norm - shift)
    features = jnp.concatenate([trig_scale * sin, trig_scale * cos,
                                jnp.exp(projected - (half_sq_norm + shift))], axis=-2)
    basis = jnp.concatenate([jnp.ones_like(half_sq_norm)] + _sign_rows(queries, xi), axis=-2)
    return jnp.einsum("...fl,...sl->...fs", features, basis)


def _key_scores(keys: jax.Array, weights: jax.Array, projections: ft.Projections,
                stabilize: bool) -> jax.Array:
    """``sum_f F_k,f sum_s weights_fs [1, S_k]_s`` for token rows ``keys (..., d, L)`` and
    ``weights (..., 3m, 1 + r)`` -> ``(..., L)``.

    Written as ``m`` rounds of elementwise operations on ``(..., 1, L)`` rows, one per
    projection ``omega_j``: XLA's CPU backend makes them one loop over the keys, in which
    ``sin``, ``cos`` and ``exp`` of ``omega_j k`` share their argument and nothing of size
    ``3m x L`` is written to memory."""
    omega, xi = projections.omega, projections.xi
    m = omega.shape[0]
    half_sq_norm = _half_sq_norm(keys)
    shift = _hybrid_shift(half_sq_norm, _rows(omega, keys), stabilize)
    signs = _sign_rows(keys, xi)

    def signed_weight(f):  # (..., 1, L): weights[f] . [1, S_k]
        out = weights[..., f, 0, None, None]
        for s, sign in enumerate(signs):
            out = out + weights[..., f, s + 1, None, None] * sign
        return out

    trig, positive = 0.0, 0.0
    for j in range(m):
        projected = _rows(omega[j:j + 1], keys)
        sin, cos = ft.sincos(projected)
        trig = trig + sin * signed_weight(j) + cos * signed_weight(m + j)
        positive = positive + jnp.exp(projected - (half_sq_norm + shift)) * signed_weight(2 * m + j)
    return (jnp.exp(half_sq_norm - shift) * trig + positive)[..., 0, :]


def hybrid_scores_rows(queries: jax.Array, keys: jax.Array, projections: ft.Projections, *,
                       stabilize: bool = True) -> jax.Array:
    """:func:`hybrid_scores` for token rows: ``queries, keys (..., d, L)`` -> ``(..., L)``.

    With ``F = [T, E]`` a token's ``2m`` trigonometric and ``m`` positive features and ``S``
    its ``r`` signs, one query-key term is ``(T_q.T_k (1 + S_q.S_k / r) + E_q.E_k (1 -
    S_q.S_k / r)) / 2``; each ``T`` carries the factor ``exp(|x|^2/2 - shift)`` of its token.
    Summed over queries this needs the moments ``F_Q^T [1, S_Q]`` (``3m x (1 + r)``, one
    product with inner dimension ``L``). A key's score is then ``F_k . W [1, S_k]``, with
    ``W`` the moments weighted by the sign term's ``1`` and ``+-1/r``: ``3m (1 + r)``
    multiply-adds per key, computed with the key's features in one loop (:func:`_key_scores`).

    Layout, for XLA's CPU backend: tokens are the minor axis, so every elementwise stage is a
    loop over ``L``; ``sin`` and ``cos`` are :func:`features.sincos` (multiply-adds).
    """
    m, r = projections.omega.shape[0], projections.xi.shape[0]
    moments = _query_moments(queries, projections, stabilize)
    sign_weights = jnp.concatenate([jnp.ones(1), jnp.full(r, 1.0 / r)]).astype(moments.dtype)
    positive_sign = jnp.concatenate([jnp.ones(1), -jnp.ones(r)]).astype(moments.dtype)
    weights = moments * sign_weights
    weights = jnp.concatenate([weights[..., :2 * m, :], weights[..., 2 * m:, :] * positive_sign], axis=-2)
    return _key_scores(keys, weights, projections, stabilize) / (2.0 * m)


def hybrid_scores(queries: jax.Array, keys: jax.Array, projections: ft.Projections, *,
                  stabilize: bool = True) -> jax.Array:
    """The hybrid kernel's linear scores without building the ``3m(r+1)`` features.

    Equal to ``linear_scores(feature_map("hybrid", Q, query), feature_map("hybrid", K, key))``
    (up to float rounding) but in ``O(L m r)`` with ``m + r`` transcendentals per token; see
    :func:`hybrid_scores_rows`, which this calls on the transposed inputs.

    Args:
      queries, keys: ``(L, d)``.
      projections: hybrid projections (``omega (m, d)``, ``xi (r, d)``).
      stabilize: one log-shift per side, as in :func:`features.feature_map`.

    Returns:
      ``(L,)`` scores.
    """
    return hybrid_scores_rows(queries.T, keys.T, projections, stabilize=stabilize)


def relu_scores_rows(queries: jax.Array, keys: jax.Array) -> jax.Array:
    """``linear_scores`` of the ReLU features for token rows ``queries, keys (..., d, L)`` -> ``(..., L)``."""
    query_sums = jnp.sum(jax.nn.relu(queries) + ft.RELU_EPSILON, axis=-1, keepdims=True)  # (..., d, 1)
    key_features = jax.nn.relu(keys) + ft.RELU_EPSILON
    scores = key_features[..., 0, :] * query_sums[..., 0, :]
    for e in range(1, keys.shape[-2]):
        scores = scores + key_features[..., e, :] * query_sums[..., e, :]
    return scores


TOP_L_BLOCK = 128  # scores per block of top_l's two-level search


def top_l(scores: jax.Array, l: int) -> jax.Array:
    """Indices ``(l,)`` of the ``l`` largest of the finite ``scores (L,)``, best first; ties go
    to the lower index: the same indices as ``jax.lax.top_k(scores, l)[1]``.

    Two levels: the maxima of blocks of :data:`TOP_L_BLOCK` consecutive scores (one vectorised
    pass over ``L``), then ``l`` rounds that each take the first block holding the largest
    remaining score and the first position of that score in the block (earlier picks masked),
    ``O(L + l (L / b + l b))`` in all. Inside a loop (the rollout's ``scan``) XLA's CPU backend
    lowers ``lax.top_k`` to a full stable sort of ``L`` with a comparator call per comparison,
    which at ``L = 19,200`` cost several milliseconds per image.
    """
    size = scores.shape[-1]
    block = min(size, TOP_L_BLOCK)
    n_blocks = -(-size // block)
    if n_blocks * block != size:  # padding at the end is never picked while finite scores remain
        scores = jnp.concatenate([scores, jnp.full((n_blocks * block - size,), -jnp.inf, scores.dtype)])
    blocks = scores.reshape(n_blocks, block)
    block_max = jnp.max(blocks, axis=1)
    positions = jnp.arange(block)
    picked = []
    for _ in range(l):
        b = jnp.argmax(block_max)
        row = blocks[b]
        for earlier in picked:
            row = jnp.where(b * block + positions == earlier, -jnp.inf, row)
        picked.append(b * block + jnp.argmax(row))
        row = jnp.where(positions == picked[-1] - b * block, -jnp.inf, row)
        block_max = block_max.at[b].set(jnp.max(row))
    return jnp.stack(picked).astype(jnp.int32)


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
      batch_chunk: ``relu``/``hybrid`` under ``vmap``: images scored together per step of a
        loop over the batch (at most half the batch, so the loop has two steps or more);
        ``None`` picks as many as hold about :data:`CHUNK_TOKENS` patches (2 images at
        ``L = 19,200``, 64 of 100x100 images with 4-pixel patches). Changes speed only, never
        results.
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
    batch_chunk: int | None = None

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
        if self.batch_chunk is not None and (not isinstance(self.batch_chunk, int)
                                             or isinstance(self.batch_chunk, bool) or self.batch_chunk <= 0):
            raise ValueError(f"AttentionConfig.batch_chunk must be a positive integer or None, got {self.batch_chunk!r}")
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

    def query_key_rows(self, params: AttentionParams, image: jax.Array) -> jax.Array:
        """``image (H, W, C)`` -> queries and keys as token rows ``(2d, L)`` (queries first),
        input scaling applied: :meth:`queries_keys`, transposed.

        Non-overlapping patches: the patches of :meth:`queries_keys` ``(L, c)`` contracted
        with ``[W_Q | W_K]^T`` on ``c``, giving ``(2d, L)`` directly. (On XLA CPU at ``L =
        19,200`` this was faster than ``(patches @ W).T``, which writes ``(L, 2d)`` and then
        transposes it, and than a product with the image reshaped to ``(rows, p, cols, p*C)``,
        for which XLA transposes the whole image into ``(c, L)`` planes.) Overlapping patches:
        the strided convolution of :meth:`queries_keys` with channel-major output.
        """
        cfg = self.config
        p, channels, d = cfg.patch_size, self.image_shape[2], cfg.d_qk
        weights = jnp.concatenate([params.w_q, params.w_k], axis=1)  # (c, 2d)
        image = image.astype(weights.dtype)
        if cfg.step == p:
            patches, _ = extract_patches(image, p, p)
            projected = jax.lax.dot_general(weights.T, patches, (((1,), (1,)), ((), ())))  # (2d, L)
        else:
            projected = jax.lax.conv_general_dilated(
                image[None], weights.reshape(p, p, channels, 2 * d),
                window_strides=(cfg.step, cfg.step), padding="VALID",
                dimension_numbers=("NHWC", "HWIO", "NCHW"))[0]
        projected = projected.reshape(2 * d, self.num_patches)
        if params.b_q is not None:
            projected = projected + jnp.concatenate([params.b_q, params.b_k])[:, None]
        return jnp.concatenate([self.scale_rows(projected[:d]), self.scale_rows(projected[d:])])

    def scale_rows(self, u: jax.Array) -> jax.Array:
        """:meth:`scale_inputs` for token rows ``u (d, L)``."""
        cfg = self.config
        if cfg.scaling == "eq4":
            return u * cfg.d_qk ** -0.25
        if cfg.scaling == "eq5":
            norm = jnp.linalg.norm(u, axis=0, keepdims=True)
            return cfg.eq5_scale * u / jnp.maximum(norm, 1e-12)
        return u

    @property
    def batch_chunk(self) -> int:
        """Images scored together under ``vmap`` (``config.batch_chunk`` or from :data:`CHUNK_TOKENS`),
        before the chunk rule's cap at half the batch."""
        if self.config.batch_chunk is not None:
            return self.config.batch_chunk
        return max(1, CHUNK_TOKENS // self.num_patches)

    def _row_scores(self, params: AttentionParams, projections: ft.Projections,
                    image: jax.Array) -> jax.Array:
        """ReLU or hybrid scores ``(L,)`` of one image from its token rows."""
        d = self.config.d_qk
        rows = self.query_key_rows(params, image)
        if self.config.kernel == "relu":
            return relu_scores_rows(rows[:d], rows[d:])
        return hybrid_scores_rows(rows[:d], rows[d:], projections, stabilize=True)

    def _chunked_row_scores(self):
        """:meth:`_row_scores`, whose ``vmap`` over a batch loops over chunks of
        :attr:`batch_chunk` images, at most half the batch (a ``vmap`` inside a ``lax.map``),
        so that each chunk's ``(features, L)`` intermediates stay in cache."""
        batched = jax.custom_batching.custom_vmap(self._row_scores)

        @batched.def_vmap
        def _rule(axis_size, in_batched, params, projections, image):
            args, in_batched = (params, projections, image), tuple(in_batched)
            per_image = jax.tree.map(lambda x, b: x if b else None, args, in_batched)
            shared = jax.tree.map(lambda x, b: None if b else x, args, in_batched)

            def one_chunk(part):
                merged = jax.tree.map(lambda c, x, b: c if b else x, part, shared, in_batched,
                                      is_leaf=lambda x: x is None)
                axes = jax.tree.map(lambda b: 0 if b else None, in_batched)
                return jax.vmap(self._row_scores, in_axes=axes)(*merged)

            # At least two chunks: with the whole batch in one step (a loop of one trip is
            # removed), XLA's CPU backend fused the scores' computation into both consumers in
            # top_l, computing it twice (dev run at 100x100, L = 625, 16 images per device:
            # 1.5x the time of two chunks of 8).
            chunk = min(self.batch_chunk, -(-axis_size // 2))
            return chunks.map_chunks(one_chunk, per_image, chunk, axis_size), True

        return batched

    def scores(self, params: AttentionParams, projections: ft.Projections,
               image: jax.Array) -> jax.Array:
        """Every patch's score ``(L,)`` for one image ``(H, W, C)``."""
        cfg = self.config
        if cfg.kernel in ROW_KERNELS:
            return self._chunked_row_scores()(params, projections, image)
        queries, keys = self.queries_keys(params, image)
        if cfg.kernel == "brute":
            return brute_scores(queries, keys, row_normalize=cfg.row_normalize)
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
