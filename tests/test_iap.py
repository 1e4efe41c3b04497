"""Patches, scores and top-l selection against direct computations (slicing, loops, L x L)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from iap_mjx.attention import features as ft
from iap_mjx.attention.layer import KERNELS, AttentionConfig, IAPAttention
from iap_mjx.attention.patches import extract_patches
from iap_mjx.attention.scores import brute_scores, hybrid_scores, linear_scores
from iap_mjx.attention.selection import top_l


def random_image(shape, seed=0):
    return jax.random.uniform(jax.random.PRNGKey(seed), shape)


@pytest.mark.parametrize(
    "shape,patch,stride",
    [
        ((12, 16, 3), 4, 4),
        ((12, 16, 3), 4, 2),
        ((9, 9, 2), 3, 1),
        ((6, 5, 4), 1, 1),
        ((10, 10, 3), 2, 4),
    ],
)
def test_patches_equal_direct_slicing(shape, patch, stride):
    image = random_image(shape)
    patches, centres = jax.jit(extract_patches, static_argnums=(1, 2))(image, patch, stride)
    rows, cols = (shape[0] - patch) // stride + 1, (shape[1] - patch) // stride + 1
    assert patches.shape == (rows * cols, patch * patch * shape[2])
    img = np.asarray(image)
    for index in range(rows * cols):
        i, j = divmod(index, cols)
        top, left = i * stride, j * stride
        np.testing.assert_array_equal(patches[index], img[top : top + patch, left : left + patch].reshape(-1))
        expected_centre = [(top + patch / 2) / shape[0], (left + patch / 2) / shape[1]]
        np.testing.assert_allclose(centres[index], expected_centre, rtol=1e-6)
    assert float(centres.min()) >= 0 and float(centres.max()) <= 1


def test_patches_that_do_not_tile_raise():
    with pytest.raises(ValueError, match="do not tile the image"):
        extract_patches(jnp.zeros((10, 10, 3)), 3)
    with pytest.raises(ValueError, match=r"patch_size must be at most the image.s height and width \(4 x 4\), got 5\."):
        extract_patches(jnp.zeros((4, 4, 3)), 5)
    with pytest.raises(ValueError, match="stride must be an int >= 1"):
        extract_patches(jnp.zeros((4, 4, 3)), 2, 0)


def test_brute_scores_equal_a_plain_loop():
    q = np.asarray(jax.random.normal(jax.random.PRNGKey(1), (30, 4)) * 0.7)
    k = np.asarray(jax.random.normal(jax.random.PRNGKey(2), (30, 4)) * 0.7)
    loop = np.zeros(30)
    loop_normalised = np.zeros(30)
    for i in range(30):
        row = [math.exp(float(np.dot(q[i], k[j]))) for j in range(30)]
        for j in range(30):
            loop[j] += row[j]
            loop_normalised[j] += row[j] / sum(row)
    plain = np.asarray(brute_scores(jnp.asarray(q), jnp.asarray(k)))
    # Unnormalised scores come scaled by one positive constant (overflow guard): compare ratios.
    np.testing.assert_allclose(plain / plain.sum(), loop / loop.sum(), rtol=1e-5)
    np.testing.assert_allclose(
        brute_scores(jnp.asarray(q), jnp.asarray(k), row_normalize=True), loop_normalised, rtol=1e-5
    )


@pytest.mark.parametrize("kind", ft.KINDS)
def test_linear_scores_equal_explicit_column_sums(kind):
    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    q = jax.random.normal(keys[0], (50, 4)) * 0.5
    k = jax.random.normal(keys[1], (50, 4)) * 0.5
    proj = ft.draw_projections(keys[2], kind, m=6, d=4, r=3)
    qf = ft.feature_map(kind, q, proj, role="query")
    kf = ft.feature_map(kind, k, proj, role="key")
    explicit = np.asarray(qf @ kf.T).sum(axis=0)  # the L x L matrix, built on purpose
    np.testing.assert_allclose(linear_scores(qf, kf), explicit, rtol=1e-4, atol=1e-5)


def test_factorised_hybrid_scores_equal_the_feature_map():
    keys = jax.random.split(jax.random.PRNGKey(4), 3)
    q = jax.random.normal(keys[0], (80, 4))
    k = jax.random.normal(keys[1], (80, 4))
    proj = ft.draw_projections(keys[2], "hybrid", m=10, d=4, r=5)
    for stabilize in (False, True):
        via_features = linear_scores(
            ft.feature_map("hybrid", q, proj, role="query", stabilize=stabilize),
            ft.feature_map("hybrid", k, proj, role="key", stabilize=stabilize),
        )
        fast = hybrid_scores(q, k, proj, stabilize=stabilize)
        np.testing.assert_allclose(fast, via_features, rtol=2e-4, atol=1e-4 * float(jnp.abs(via_features).max()))


def test_factorised_hybrid_scores_survive_norm_10_and_keep_the_ranking():
    """Norms up to 10 overflow float32 without the shift (exp(50) squared); with it the
    scores stay finite and rank the keys as the stabilised feature maps do."""
    keys = jax.random.split(jax.random.PRNGKey(5), 4)
    directions = jax.random.normal(keys[0], (2, 80, 4))
    directions = directions / jnp.linalg.norm(directions, axis=-1, keepdims=True)
    norms = jax.random.uniform(keys[1], (2, 80, 1), minval=8.0, maxval=10.0)
    q, k = directions * norms
    proj = ft.draw_projections(keys[2], "hybrid", m=10, d=4, r=5)
    fast = np.asarray(jax.jit(hybrid_scores)(q, k, proj))
    via_features = np.asarray(
        linear_scores(
            ft.feature_map("hybrid", q, proj, role="query", stabilize=True),
            ft.feature_map("hybrid", k, proj, role="key", stabilize=True),
        )
    )
    assert np.all(np.isfinite(fast))
    np.testing.assert_array_equal(np.argsort(-fast)[:10], np.argsort(-via_features)[:10])


def test_top_l_breaks_ties_toward_the_lower_index():
    scores = jnp.array([1.0, 3.0, 2.0, 3.0, 3.0, 0.0])
    np.testing.assert_array_equal(jax.jit(top_l, static_argnums=1)(scores, 4), [1, 3, 4, 2])


def layer_for(kernel, shape=(20, 20, 3), **overrides):
    cfg = AttentionConfig(kernel=kernel, patch_size=overrides.pop("patch_size", 4), top_l=5, m=6, r=3, **overrides)
    return IAPAttention(cfg, shape)


@pytest.mark.parametrize("use_bias", [False, True])
@pytest.mark.parametrize("scaling", ["eq4", "eq5", "none"])
def test_layer_queries_keys_equal_patches_times_weights(scaling, use_bias):
    layer = layer_for("hybrid", patch_size=4, stride=2, scaling=scaling, use_bias=use_bias, eq5_scale=1.3)
    params = layer.init(jax.random.PRNGKey(0))
    if use_bias:
        params = params.replace(b_q=jnp.arange(4.0) * 0.1, b_k=-jnp.arange(4.0) * 0.1)
    image = random_image((20, 20, 3), seed=5)
    patches, _ = extract_patches(image, 4, 2)
    q_direct = patches @ params.w_q + (params.b_q if use_bias else 0)
    k_direct = patches @ params.w_k + (params.b_k if use_bias else 0)
    if scaling == "eq4":
        q_direct, k_direct = q_direct * 4**-0.25, k_direct * 4**-0.25
    elif scaling == "eq5":
        q_direct = 1.3 * q_direct / jnp.linalg.norm(q_direct, axis=-1, keepdims=True)
        k_direct = 1.3 * k_direct / jnp.linalg.norm(k_direct, axis=-1, keepdims=True)
    q, k = jax.jit(layer.queries_keys)(params, image)
    np.testing.assert_allclose(q, q_direct, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(k, k_direct, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("kernel", KERNELS)
def test_layer_under_jit_and_vmap_selects_the_best_scores(kernel):
    layer = layer_for(kernel)
    params = layer.init(jax.random.PRNGKey(1))
    projections = layer.draw_projections(jax.random.PRNGKey(2))
    images = jax.random.uniform(jax.random.PRNGKey(3), (3, 20, 20, 3))
    batched = jax.jit(jax.vmap(lambda img: layer(params, projections, img, with_patches=True)))
    selection = batched(images)
    assert selection.indices.shape == (3, 5) and selection.centres.shape == (3, 5, 2)
    assert selection.patches.shape == (3, 5, 48)
    for b in range(3):
        single = layer(params, projections, images[b], with_patches=True)
        np.testing.assert_array_equal(selection.indices[b], single.indices)
        scores = np.asarray(single.scores)
        assert np.all(np.isfinite(scores))
        best = np.sort(scores)[::-1][:5]
        np.testing.assert_allclose(scores[np.asarray(single.indices)], best, rtol=1e-6)
        patches, centres = extract_patches(images[b], 4)
        np.testing.assert_array_equal(single.patches, patches[single.indices])
        np.testing.assert_array_equal(single.centres, centres[single.indices])


def test_layer_scores_equal_the_explicit_kernel_matrix():
    """End to end: the layer's hybrid scores are column sums of phi(Q) phi(K)^T."""
    layer = layer_for("hybrid", scaling="eq4")
    params = layer.init(jax.random.PRNGKey(7))
    proj = layer.draw_projections(jax.random.PRNGKey(8))
    image = random_image((20, 20, 3), seed=9)
    patches, _ = extract_patches(image, 4)
    q = patches @ params.w_q * 4**-0.25
    k = patches @ params.w_k * 4**-0.25
    matrix = ft.feature_map("hybrid", q, proj, role="query") @ ft.feature_map("hybrid", k, proj, role="key").T
    explicit = np.asarray(matrix).sum(0)
    scores = np.asarray(layer.scores(params, proj, image))
    ratio = scores / explicit  # the stabiliser scales every score by one positive constant
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-3)
    assert ratio[0] > 0


def test_layer_errors_are_clear_and_early():
    with pytest.raises(
        ValueError, match=r"AttentionConfig\.top_l must be at most the number of patches L = 25 .*, got 30\."
    ):
        IAPAttention(AttentionConfig(patch_size=4, top_l=30), (20, 20, 3))
    with pytest.raises(ValueError, match="do not tile"):
        IAPAttention(AttentionConfig(patch_size=3), (20, 20, 3))
    with pytest.raises(
        ValueError, match="AttentionConfig.kernel must be one of brute, relu, exp, trig, hybrid, angular"
    ):
        AttentionConfig(kernel="softmax")
    with pytest.raises(ValueError, match="AttentionConfig.m must be an int >= 1"):
        AttentionConfig(m=0)
    with pytest.raises(ValueError, match="AttentionConfig.stride must be an int >= 1 or None"):
        AttentionConfig(stride=True)
    for scale in (0.0, float("inf"), "1"):
        with pytest.raises(ValueError, match=r"AttentionConfig.eq5_scale must be a finite number > 0, got"):
            AttentionConfig(eq5_scale=scale)
    with pytest.raises(ValueError, match="AttentionConfig.scaling must be one of eq4, eq5, none"):
        AttentionConfig(scaling="eq6")
    with pytest.raises(ValueError, match="AttentionConfig.row_normalize must be false with kernel"):
        AttentionConfig(kernel="hybrid", row_normalize=True)
    layer = layer_for("relu")
    with pytest.raises(ValueError, match=r"image of shape \(10, 10, 3\)"):
        layer(layer.init(jax.random.PRNGKey(0)), layer.draw_projections(jax.random.PRNGKey(0)), jnp.zeros((10, 10, 3)))


def test_config_is_hashable_for_static_arguments():
    cfg = AttentionConfig()
    assert hash(cfg) == hash(AttentionConfig())
    assert hash(IAPAttention(cfg, (20, 20, 3))) == hash(IAPAttention(cfg, (20, 20, 3)))


@pytest.mark.parametrize("size", [25, 200, 625, 19200])
def test_top_l_equals_lax_top_k_with_ties(size):
    """The two-level search returns lax.top_k's indices, ties to the lower index, for sizes
    that are and are not multiples of the block, with many ties and with none."""
    rng = np.random.default_rng(size)
    rows = np.stack(
        [
            rng.normal(size=size),
            rng.integers(0, 4, size=size),  # distinct / heavy ties
            np.ones(size),
            np.arange(size),
            -np.arange(size),
        ]
    ).astype(np.float32)
    top = jax.jit(jax.vmap(top_l, in_axes=(0, None)), static_argnums=1)
    for l in (1, 10):
        np.testing.assert_array_equal(top(jnp.asarray(rows), l), jax.lax.top_k(jnp.asarray(rows), l)[1])


@pytest.mark.parametrize(
    "scaling,use_bias,stride", [("eq4", False, None), ("eq5", True, None), ("none", False, 2), ("eq4", True, 2)]
)
def test_query_key_rows_are_the_transposed_queries_and_keys(scaling, use_bias, stride):
    layer = layer_for("hybrid", patch_size=4, stride=stride, scaling=scaling, use_bias=use_bias)
    params = layer.init(jax.random.PRNGKey(0))
    if use_bias:
        params = params.replace(b_q=jnp.arange(4.0) * 0.1, b_k=-jnp.arange(4.0) * 0.1)
    image = random_image((20, 20, 3), seed=6)
    q, k = layer.queries_keys(params, image)
    rows = jax.jit(layer.query_key_rows)(params, image)
    np.testing.assert_allclose(rows, jnp.concatenate([q, k], axis=1).T, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("kernel", ["hybrid", "relu"])
def test_layer_scores_equal_the_feature_map_path_at_patch_2(kernel):
    """The token-row scores of the layer (hybrid: moments and key scores as products; relu)
    equal linear_scores of the feature maps of queries_keys, and select the same patches,
    on an image with 2-pixel patches (L = 768) whose pixels have structure as rendered ones do."""
    cfg = AttentionConfig(kernel=kernel, patch_size=2, top_l=10, m=10, r=5)
    layer = IAPAttention(cfg, (48, 64, 3))
    params = layer.init(jax.random.PRNGKey(11))
    proj = layer.draw_projections(jax.random.PRNGKey(12))
    yy, xx = np.mgrid[0:48, 0:64] / 48.0
    image = jnp.asarray(np.stack([np.sin(3 * xx) ** 2, yy, (xx * yy) % 0.3], axis=-1), jnp.float32)
    image = image + 0.05 * random_image((48, 64, 3), seed=13)
    q, k = layer.queries_keys(params, image)
    expected = linear_scores(
        ft.feature_map(kernel, q, proj, role="query", stabilize=True),
        ft.feature_map(kernel, k, proj, role="key", stabilize=True),
    )
    scores = jax.jit(layer.scores)(params, proj, image)
    scale = float(jnp.abs(expected).max())
    np.testing.assert_allclose(scores, expected, rtol=1e-4, atol=1e-5 * scale)
    np.testing.assert_array_equal(jax.jit(layer)(params, proj, image).indices, jax.lax.top_k(expected, 10)[1])


@pytest.mark.parametrize("batched_projections", [False, True])
def test_vmap_in_chunks_equals_one_image_at_a_time(batched_projections):
    """Under vmap the layer scores its batch in chunks (here 2 images, 5 images: the last chunk
    padded); per-image parameters and per-image or shared projections give each image's own
    result."""
    layer = layer_for("hybrid", batch_chunk=2)
    params = layer.init(jax.random.PRNGKey(1))
    params = jax.tree.map(lambda x: x + 0.1 * jax.random.normal(jax.random.PRNGKey(2), (5,) + x.shape), params)
    keys = jax.random.split(jax.random.PRNGKey(3), 5)
    projections = jax.vmap(layer.draw_projections)(keys) if batched_projections else layer.draw_projections(keys[0])
    images = jax.random.uniform(jax.random.PRNGKey(4), (5, 20, 20, 3))
    axes = (0, 0 if batched_projections else None, 0)
    batched = jax.jit(jax.vmap(lambda p, r, x: layer(p, r, x), in_axes=axes))(params, projections, images)
    for b in range(5):
        one = jax.tree.map(lambda x: x[b], params)
        proj = jax.tree.map(lambda x: x[b], projections) if batched_projections else projections
        single = layer(one, proj, images[b])
        np.testing.assert_allclose(
            batched.scores[b], single.scores, rtol=1e-5, atol=1e-6 * float(jnp.abs(single.scores).max())
        )
        np.testing.assert_array_equal(batched.indices[b], single.indices)


def test_batch_chunk_must_be_positive():
    with pytest.raises(ValueError, match="AttentionConfig.batch_chunk must be an int >= 1 or None"):
        AttentionConfig(batch_chunk=0)


def test_effective_stride_is_the_stride_or_else_the_patch_size():
    assert AttentionConfig(patch_size=4).effective_stride == 4
    assert AttentionConfig(patch_size=4, stride=2).effective_stride == 2
