"""The Implicit Attention for Pixels layer: image -> patch scores -> the top ``l`` patches.

Each flattened patch ``x`` (:mod:`~iap_mjx.attention.patches`) gives a query ``q = x W_Q``
and a key ``k = x W_K`` of dimension ``d``; the patches are scored by a kernel
(:mod:`~iap_mjx.attention.scores`: brute force or a linear-time feature map) and the policy sees
the ``l`` best-scoring patches (:mod:`~iap_mjx.attention.selection`): their centres,
optionally their pixels.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from flax import struct

from iap_mjx import chunks
from iap_mjx.attention import features as ft
from iap_mjx.attention.patches import extract_patches, patch_centres, patch_corner, patch_grid
from iap_mjx.attention.scores import brute_scores, hybrid_scores_rows, linear_scores, relu_scores_rows
from iap_mjx.attention.selection import top_l
from iap_mjx.checks import require_choice, require_int, require_number

KERNELS = ("brute",) + ft.KINDS
SCALINGS = ("eq4", "eq5", "none")
ROW_KERNELS = ("relu", "hybrid")  # scored from token rows (tokens minor), in chunks under vmap
# Patches scored together per chunk under vmap when batch_chunk is None: about 2 images at
# L = 19,200, few enough that the row-score intermediates stay in cache.
CHUNK_TOKENS = 40_000


@dataclasses.dataclass(frozen=True)
class AttentionConfig:
    """Static settings of one IAP attention layer (hashable: safe as a ``jit`` static arg).

    Attributes:
      patch_size: patch side ``p`` in pixels (1 = one pixel per patch).
      stride: step between patches; ``None`` means ``patch_size`` (no overlap).
      d_qk: query/key dimension ``d``.
      top_l: number of patches ``l`` passed on to the controller.
      kernel: ``"brute"`` (explicit softmax) or a feature map kind (:data:`features.KINDS`).
      m: random features (``exp``/``trig``/``hybrid``).
      r: sign features (``hybrid``, ``angular``).
      orthogonal: block-orthogonal random projections (else iid Gaussian).
      scaling: ``"eq4"`` (``x = d^{-1/4} u``), ``"eq5"`` (``x = c u / |u|``) or ``"none"``.
      eq5_scale: the constant ``c`` of eq. 5.
      row_normalize: brute force only: softmax each row (Tang et al.'s AttentionAgent).
      use_bias: affine ``x W + b`` queries/keys instead of linear.
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
    batch_chunk: int | None = None

    def __post_init__(self):
        require_choice("AttentionConfig.kernel", self.kernel, KERNELS)
        require_choice("AttentionConfig.scaling", self.scaling, SCALINGS)
        for name in ("patch_size", "d_qk", "top_l", "m", "r"):
            require_int(f"AttentionConfig.{name}", getattr(self, name))
        require_int("AttentionConfig.stride", self.stride, none_ok=True)
        require_int("AttentionConfig.batch_chunk", self.batch_chunk, none_ok=True)
        require_number("AttentionConfig.eq5_scale", self.eq5_scale, 0, low_open=True, high_open=True)
        if self.row_normalize and self.kernel != "brute":
            raise ValueError(
                f"AttentionConfig.row_normalize must be false with kernel {self.kernel!r} (IAP scores "
                "are column sums of an unnormalised attention matrix; only 'brute' normalises rows), got True."
            )

    @property
    def effective_stride(self) -> int:
        """The stride actually used: ``stride``, or ``patch_size`` if ``stride`` is ``None``."""
        return self.patch_size if self.stride is None else self.stride


class AttentionParams(struct.PyTreeNode):
    """Trainable parameters: ``w_q``, ``w_k`` ``(c, d)``; ``b_q``, ``b_k`` ``(d,)`` or ``None``."""

    w_q: jax.Array
    w_k: jax.Array
    b_q: jax.Array | None = None
    b_k: jax.Array | None = None

    @property
    def biases(self) -> tuple[jax.Array, jax.Array] | None:
        """``(b_q, b_k)``, or ``None`` without biases; ``ValueError`` if only one is set."""
        if self.b_q is None and self.b_k is None:
            return None
        if self.b_q is None or self.b_k is None:
            raise ValueError("AttentionParams: b_q and b_k are set together or not at all")
        return self.b_q, self.b_k


class Selection(struct.PyTreeNode):
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
            raise ValueError(f"IAPAttention.image_shape must be (H, W, C), got {self.image_shape!r}.")
        height, width, _ = self.image_shape
        stride = self.config.effective_stride
        patch_grid(height, width, self.config.patch_size, stride)
        if self.config.top_l > self.num_patches:
            raise ValueError(
                f"AttentionConfig.top_l must be at most the number of patches L = {self.num_patches} "
                f"({height}x{width} image, patch_size {self.config.patch_size}, stride {stride}), "
                f"got {self.config.top_l}."
            )

    @property
    def grid(self) -> tuple[int, int]:
        """Patch grid ``(rows, cols)``."""
        height, width, _ = self.image_shape
        return patch_grid(height, width, self.config.patch_size, self.config.effective_stride)

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
        return AttentionParams(
            w_q=scale * jax.random.normal(q_key, shape), w_k=scale * jax.random.normal(k_key, shape), b_q=bias, b_k=bias
        )

    def draw_projections(self, key: jax.Array) -> ft.Projections:
        """The kernel's random projections (empty for ``brute`` and ``relu``)."""
        cfg = self.config
        if cfg.kernel == "brute":
            return ft.Projections()
        return ft.draw_projections(key, cfg.kernel, m=cfg.m, d=cfg.d_qk, r=cfg.r, orthogonal=cfg.orthogonal)

    def queries_keys(self, params: AttentionParams, image: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``image (H, W, C)`` -> queries, keys ``(L, d)``, scaled: the inputs of brute force
        and of the feature maps (:func:`features.feature_map`), which take tokens on the major
        axis.

        The projection of :meth:`query_key_rows` in the other layout, computed in this one
        rather than transposed from the token rows: XLA's CPU backend rounds the two layouts'
        products differently, so the transpose would change these kernels' scores in their
        last bits, and with them the training runs that use these kernels.

        Non-overlapping patches: a reshape and one ``(L, c) @ (c, 2d)`` product. Overlapping
        patches: one strided convolution with kernel ``[W_Q | W_K]`` reshaped to
        ``(p, p, C, 2d)``, the same numbers without materialising the overlapping patches
        (where both apply, the reshape and product: XLA's CPU backend runs them as one plain matmul).
        """
        cfg = self.config
        p, stride, channels = cfg.patch_size, cfg.effective_stride, self.image_shape[2]
        weights = jnp.concatenate([params.w_q, params.w_k], axis=1)  # (c, 2d)
        if stride == p:
            patches, _ = extract_patches(image.astype(weights.dtype), p, p)
            projected = patches @ weights
        else:
            projected = jax.lax.conv_general_dilated(
                image[None].astype(weights.dtype),
                weights.reshape(p, p, channels, -1),
                window_strides=(stride, stride),
                padding="VALID",
                dimension_numbers=("NHWC", "HWIO", "NHWC"),
            )
            projected = projected.reshape(self.num_patches, 2 * cfg.d_qk)
        queries, keys = projected[:, : cfg.d_qk], projected[:, cfg.d_qk :]
        if (biases := params.biases) is not None:
            queries, keys = queries + biases[0], keys + biases[1]
        return self.scale_inputs(queries, axis=-1), self.scale_inputs(keys, axis=-1)

    def query_key_rows(self, params: AttentionParams, image: jax.Array) -> jax.Array:
        """``image (H, W, C)`` -> queries and keys as token rows ``(2d, L)`` (queries first),
        scaled: the inputs of the ReLU and hybrid kernels' row scores
        (:func:`scores.relu_scores_rows`, :func:`scores.hybrid_scores_rows`), the layer's hot
        path. The projection of :meth:`queries_keys`, transposed.

        Non-overlapping patches: the patches ``(L, c)`` contracted with ``[W_Q | W_K]^T`` on
        ``c``, giving ``(2d, L)`` directly: ``(patches @ W).T`` would write ``(L, 2d)`` and then
        transpose it, and a product with the image reshaped to ``(rows, p, cols, p*C)`` makes
        XLA transpose the whole image into ``(c, L)`` planes. Overlapping patches: the strided
        convolution of :meth:`queries_keys` with channel-major output.
        """
        cfg = self.config
        p, stride, channels, d = cfg.patch_size, cfg.effective_stride, self.image_shape[2], cfg.d_qk
        weights = jnp.concatenate([params.w_q, params.w_k], axis=1)  # (c, 2d)
        image = image.astype(weights.dtype)
        if stride == p:
            patches, _ = extract_patches(image, p, p)
            projected = jax.lax.dot_general(weights.T, patches, (((1,), (1,)), ((), ())))  # (2d, L)
        else:
            projected = jax.lax.conv_general_dilated(
                image[None],
                weights.reshape(p, p, channels, 2 * d),
                window_strides=(stride, stride),
                padding="VALID",
                dimension_numbers=("NHWC", "HWIO", "NCHW"),
            )[0]
        projected = projected.reshape(2 * d, self.num_patches)
        if (biases := params.biases) is not None:
            projected = projected + jnp.concatenate(biases)[:, None]
        return jnp.concatenate([self.scale_inputs(projected[:d], axis=0), self.scale_inputs(projected[d:], axis=0)])

    def scale_inputs(self, u: jax.Array, *, axis: int) -> jax.Array:
        """Paper eq. 4 (``d^{-1/4} u``), eq. 5 (``c u / |u|``) or identity, of queries or keys
        ``u`` whose query/key dimension ``d`` is ``axis``: ``(L, d)`` with ``axis=-1``, token rows
        ``(d, L)`` with ``axis=0``; same shape out."""
        cfg = self.config
        if cfg.scaling == "eq4":
            return u * cfg.d_qk**-0.25
        if cfg.scaling == "eq5":
            norm = jnp.linalg.norm(u, axis=axis, keepdims=True)
            return cfg.eq5_scale * u / jnp.maximum(norm, 1e-12)
        return u

    @property
    def batch_chunk(self) -> int:
        """Images scored together under ``vmap`` (``config.batch_chunk`` or from :data:`CHUNK_TOKENS`),
        before the chunk rule's cap at half the batch."""
        if self.config.batch_chunk is not None:
            return self.config.batch_chunk
        return max(1, CHUNK_TOKENS // self.num_patches)

    def _row_scores(self, params: AttentionParams, projections: ft.Projections, image: jax.Array) -> jax.Array:
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
                merged = jax.tree.map(
                    lambda c, x, b: c if b else x, part, shared, in_batched, is_leaf=lambda x: x is None
                )
                axes = jax.tree.map(lambda b: 0 if b else None, in_batched)
                return jax.vmap(self._row_scores, in_axes=axes)(*merged)

            # At least two chunks: with the whole batch in one step (a loop of one trip is
            # removed), XLA's CPU backend fuses the scores' computation into both of top_l's
            # consumers and computes it twice (BENCHMARKS.md, full pixel pipeline at 100x100).
            chunk = min(self.batch_chunk, chunks.ceil_div(axis_size, 2))
            return chunks.map_chunks(one_chunk, per_image, chunk, axis_size), True

        return batched

    def scores(self, params: AttentionParams, projections: ft.Projections, image: jax.Array) -> jax.Array:
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

    def __call__(
        self, params: AttentionParams, projections: ft.Projections, image: jax.Array, *, with_patches: bool = False
    ) -> Selection:
        """Scores all patches of ``image (H, W, C)`` and selects the top ``l``."""
        if image.shape != tuple(self.image_shape):
            raise ValueError(f"image of shape {image.shape} given to a layer built for {self.image_shape}")
        scores = self.scores(params, projections, image)
        indices = top_l(scores, self.config.top_l)
        centres = jnp.asarray(
            patch_centres(*self.image_shape[:2], self.config.patch_size, self.config.effective_stride)
        )[indices]
        patches = self.selected_patches(image, indices) if with_patches else None
        return Selection(indices=indices, centres=centres, scores=scores, patches=patches)

    def selected_patches(self, image: jax.Array, indices: jax.Array) -> jax.Array:
        """Pixels of the patches ``indices (l,)`` of ``image`` -> ``(l, p*p*C)``."""
        p, stride = self.config.patch_size, self.config.effective_stride
        _, cols = self.grid

        def one(index):
            corner = (*patch_corner(index, cols, stride), 0)
            return jax.lax.dynamic_slice(image, corner, (p, p, self.image_shape[2])).reshape(-1)

        return jax.vmap(one)(indices)
