"""Patch scores: column sums of the attention matrix, brute force and in linear time.

A patch's score is the column sum of the attention matrix, ``s_j = sum_i K(q_i, k_j)`` (paper
eq. 1 with ``r = 1``), for queries and keys ``(L, d)`` or, in the layer's layout, token rows
``(..., d, L)`` (tokens the minor axis).

- Brute force builds the ``L x L`` matrix: ``O(L^2)`` time and memory. With row
  normalisation it is Tang et al.'s AttentionAgent.
- IAP (eq. 3) computes ``(1^T phi(Q)) phi(K)^T``: ``O(L M)``, never building ``L x L``. The
  hybrid and ReLU kernels have factorised forms on token rows that never build the features
  either (:func:`hybrid_scores_rows`, :func:`relu_scores_rows`).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from iap_mjx.attention import features as ft


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
        # Column sums of the row-softmax as one matvec (1 / row sums) @ exp: XLA CPU lowers the
        # column reduction of softmax(logits) badly at some vmap batch sizes, and brute force
        # must not be a weak baseline.
        unnormalised = jnp.exp(logits - jax.lax.stop_gradient(jnp.max(logits, axis=-1, keepdims=True)))
        return (1.0 / jnp.sum(unnormalised, axis=-1)) @ unnormalised
    return jnp.sum(jnp.exp(logits - jax.lax.stop_gradient(jnp.max(logits))), axis=0)


def linear_scores(query_features: jax.Array, key_features: jax.Array) -> jax.Array:
    """IAP scores ``(1^T Q') K'^T`` from ``(L, M)`` features, in ``O(L M)``: -> ``(L,)``."""
    return key_features @ jnp.sum(query_features, axis=0)


def _unrolled_sum(term: Callable[[int], jax.Array], n: int) -> jax.Array:
    """``term(0) + term(1) + ... + term(n - 1)``, added left to right.

    A sum over the ``d`` entries of a token written out as elementwise adds: XLA's CPU backend
    fuses them into the loop over tokens around them, where a reduction or a dot with inner
    dimension ``d = 4`` would be its own kernel and a materialised buffer."""
    out = term(0)
    for e in range(1, n):
        out = out + term(e)
    return out


def _rows(matrix: jax.Array, x: jax.Array) -> jax.Array:
    """``matrix (n, d)`` times token rows ``x (..., d, L)`` -> ``(..., n, L)``."""
    return _unrolled_sum(lambda e: matrix[:, e, None] * x[..., e : e + 1, :], x.shape[-2])


def _half_sq_norm(x: jax.Array) -> jax.Array:
    """``|x|^2 / 2`` of token rows ``x (..., d, L)`` -> ``(..., 1, L)``."""
    return 0.5 * _unrolled_sum(lambda e: x[..., e : e + 1, :] * x[..., e : e + 1, :], x.shape[-2])


def _larger(a: jax.Array, b: jax.Array) -> jax.Array:
    """``max(a, b)`` elementwise as compare-and-select (the same number for non-NaN inputs).

    With ``jnp.maximum`` XLA's CPU backend (jaxlib 0.10) hands the maxima of :func:`_row_max` to
    a YNNPACK elementwise kernel and first copies each of its rows out; a select stays in XLA's
    own loop, fused with the rows' computation (the layer's kernel time with each:
    BENCHMARKS.md, full pixel pipeline at 240x320). A NaN in ``b`` is kept
    and one in ``a`` dropped; a NaN query or key makes its ``|x|^2/2`` NaN, which the shift's
    maximum over tokens propagates either way."""
    return jnp.where(a > b, a, b)


def _row_max(x: jax.Array) -> jax.Array:
    """Maximum over the rows of ``x (..., n, L)`` -> ``(..., 1, L)``, as one elementwise loop."""
    out = x[..., 0:1, :]
    for i in range(1, x.shape[-2]):
        out = _larger(x[..., i : i + 1, :], out)
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


def _hybrid_projections(projections: ft.Projections) -> tuple[jax.Array, jax.Array]:
    """``(omega (m, d), xi (r, d))``, both of which the hybrid kernel needs."""
    return ft.drawn(projections.omega, "omega", "hybrid"), ft.drawn(projections.xi, "xi", "hybrid")


def _sign_rows(x: jax.Array, xi: jax.Array) -> list[jax.Array]:
    """``sgn(xi_s x)`` of token rows ``x (..., d, L)``: ``r`` rows ``(..., 1, L)`` in ``{-1, +1}`` (0 maps to +1)."""
    return [jnp.where(_rows(xi[s : s + 1], x) >= 0, 1.0, -1.0).astype(x.dtype) for s in range(xi.shape[0])]


def _query_moments(queries: jax.Array, projections: ft.Projections, stabilize: bool) -> jax.Array:
    """``F_Q^T [1, S_Q]`` ``(..., 3m, 1 + r)``: the features ``F = [e sin(omega q); e cos(omega q);
    exp(omega q - |q|^2/2 - shift)]`` (``e = exp(|q|^2/2 - shift)``, ``(..., 3m, L)``) summed over
    the queries against ``[1; signs]``, one product with inner dimension ``L``."""
    omega, xi = _hybrid_projections(projections)
    half_sq_norm = _half_sq_norm(queries)
    projected = _rows(omega, queries)
    shift = _hybrid_shift(half_sq_norm, projected, stabilize)
    sin, cos = ft.sincos(projected)
    trig_scale = jnp.exp(half_sq_norm - shift)
    features = jnp.concatenate(
        [trig_scale * sin, trig_scale * cos, jnp.exp(projected - (half_sq_norm + shift))], axis=-2
    )
    basis = jnp.concatenate([jnp.ones_like(half_sq_norm)] + _sign_rows(queries, xi), axis=-2)
    return jnp.einsum("...fl,...sl->...fs", features, basis)


def _key_scores(keys: jax.Array, weights: jax.Array, projections: ft.Projections, stabilize: bool) -> jax.Array:
    """``sum_f F_k,f sum_s weights_fs [1, S_k]_s`` for token rows ``keys (..., d, L)`` and
    ``weights (..., 3m, 1 + r)`` -> ``(..., L)``.

    Written as ``m`` rounds of elementwise operations on ``(..., 1, L)`` rows, one per
    projection ``omega_j``: XLA's CPU backend makes them one loop over the keys, in which
    ``sin``, ``cos`` and ``exp`` of ``omega_j k`` share their argument and nothing of size
    ``3m x L`` is written to memory."""
    omega, xi = _hybrid_projections(projections)
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
        projected = _rows(omega[j : j + 1], keys)
        sin, cos = ft.sincos(projected)
        trig = trig + sin * signed_weight(j) + cos * signed_weight(m + j)
        positive = positive + jnp.exp(projected - (half_sq_norm + shift)) * signed_weight(2 * m + j)
    return (jnp.exp(half_sq_norm - shift) * trig + positive)[..., 0, :]


def hybrid_scores_rows(
    queries: jax.Array, keys: jax.Array, projections: ft.Projections, *, stabilize: bool = True
) -> jax.Array:
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
    omega, xi = _hybrid_projections(projections)
    m, r = omega.shape[0], xi.shape[0]
    moments = _query_moments(queries, projections, stabilize)
    sign_weights = jnp.concatenate([jnp.ones(1), jnp.full(r, 1.0 / r)]).astype(moments.dtype)
    positive_sign = jnp.concatenate([jnp.ones(1), -jnp.ones(r)]).astype(moments.dtype)
    weights = moments * sign_weights
    weights = jnp.concatenate([weights[..., : 2 * m, :], weights[..., 2 * m :, :] * positive_sign], axis=-2)
    return _key_scores(keys, weights, projections, stabilize) / (2.0 * m)


def hybrid_scores(
    queries: jax.Array, keys: jax.Array, projections: ft.Projections, *, stabilize: bool = True
) -> jax.Array:
    """The hybrid kernel's linear scores without building the ``3m(r+1)`` features.

    Equal to ``linear_scores(feature_map("hybrid", Q, query), feature_map("hybrid", K, key))``
    (up to float rounding) but in ``O(L m r)``, per token ``m`` exponentials, ``m`` polynomial
    sine-cosine pairs and ``r`` sign tests; see
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
    return _unrolled_sum(lambda e: key_features[..., e, :] * query_sums[..., e, :], keys.shape[-2])
