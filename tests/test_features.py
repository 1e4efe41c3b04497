"""The kernel estimators against their closed forms (iap-math.md sections 3-5).

Every statistical check uses a fixed seed and a tolerance of ``Z`` standard errors, the
standard error coming from the estimator's own spread over the draws: a correct estimator
fails with probability about 1e-6 per check, a wrong one by many standard errors (see
``test_symmetric_hybrid_map_is_caught``, which runs the same check on a deliberately broken map).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from iap_mjx.attention import features as ft

D, M, R = 4, 10, 5
DRAWS = 100_000
Z = 5.0  # standard errors allowed

# (|x|, |y|, theta): equal and unequal norms, theta from 0 to pi.
POINTS = [
    (0.8, 0.8, 0.0),
    (0.8, 0.8, 0.05),
    (0.8, 0.8, math.pi / 3),
    (0.8, 0.8, 2 * math.pi / 3),
    (0.8, 0.8, math.pi - 0.05),
    (0.8, 0.8, math.pi),
    (1.0, 0.6, math.pi / 4),
    (0.5, 1.1, math.pi / 2),
    (1.2, 1.2, 3 * math.pi / 4),
]


def pair(norm_x: float, norm_y: float, theta: float) -> tuple[np.ndarray, np.ndarray]:
    """Two ``(D,)`` vectors with the given norms and angle, in a fixed random plane."""
    basis, _ = np.linalg.qr(np.random.default_rng(7).normal(size=(D, 2)))
    e1, e2 = basis[:, 0], basis[:, 1]
    return (norm_x * e1).astype(np.float32), (norm_y * (math.cos(theta) * e1 + math.sin(theta) * e2)).astype(np.float32)


XS, YS = map(np.stack, zip(*(pair(*p) for p in POINTS)))  # (P, D) each


def estimates(kind: str, *, orthogonal: bool, seed: int = 0, query_role_for_keys: bool = False):
    """``(DRAWS, P)`` estimates of ``K(x_p, y_p)``, one fresh projection draw per row."""

    @jax.jit
    def run(keys):
        def one(key):
            proj = ft.draw_projections(key, kind, m=M, d=D, r=R, orthogonal=orthogonal)
            qf = ft.feature_map(kind, XS, proj, role="query")
            kf = ft.feature_map(kind, YS, proj, role="query" if query_role_for_keys else "key")
            return jnp.sum(qf * kf, axis=-1)

        return jax.vmap(one)(keys)

    return np.asarray(run(jax.random.split(jax.random.PRNGKey(seed), DRAWS)), dtype=np.float64)


def exact(kind: str) -> np.ndarray:
    x, y = XS.astype(np.float64), YS.astype(np.float64)
    if kind == "angular":
        cos = np.sum(x * y, -1) / (np.linalg.norm(x, axis=-1) * np.linalg.norm(y, axis=-1))
        return 1 - 2 * np.arccos(np.clip(cos, -1, 1)) / np.pi
    return np.exp(np.sum(x * y, -1))


def bias_ratio(samples: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``|mean - truth|`` over its tolerance, per point: below 1 passes.

    The tolerance is ``Z`` standard errors plus float32 rounding (relative 1e-5), which is
    what remains where an estimator has no variance (e.g. ``exp`` at ``x = -y``).
    """
    error = np.abs(samples.mean(0) - truth)
    stderr = samples.std(0) / math.sqrt(len(samples))
    return error / (Z * stderr + 1e-5 * np.abs(truth) + 1e-7)


@pytest.mark.parametrize("orthogonal", [False, True], ids=["iid", "orthogonal"])
@pytest.mark.parametrize("kind", ["exp", "trig", "hybrid", "angular"])
def test_estimators_are_unbiased(kind, orthogonal):
    ratio = bias_ratio(estimates(kind, orthogonal=orthogonal), exact(kind))
    assert np.all(ratio < 1), f"{kind}: bias {ratio.max():.1f}x its tolerance at {POINTS[int(ratio.argmax())]}"


def test_symmetric_hybrid_map_is_caught():
    """The same check fails when the beta block has one sign on both sides (the classic bug)."""
    ratio = bias_ratio(estimates("hybrid", orthogonal=False, query_role_for_keys=True), exact("hybrid"))
    assert ratio.max() > 10


@pytest.mark.parametrize("kind", ft.MSE_KINDS)
def test_monte_carlo_mse_matches_closed_form(kind):
    samples = estimates(kind, orthogonal=False, seed=1)
    squared_errors = (samples - exact(kind)) ** 2
    mse = squared_errors.mean(0)
    stderr = squared_errors.std(0) / math.sqrt(DRAWS)
    closed = np.asarray(ft.closed_form_mse(kind, jnp.asarray(XS), jnp.asarray(YS), m=M, r=R), np.float64)
    # float32 features: allow rounding error of the estimate itself (relative 1e-6).
    rounding = (1e-6 * exact(kind)) ** 2
    assert np.all(np.abs(mse - closed) <= Z * stderr + rounding), f"{kind}: empirical {mse} vs closed form {closed}"


def test_hybrid_error_vanishes_at_zero_and_pi_for_equal_norms():
    closed = np.asarray(ft.closed_form_mse("hybrid", jnp.asarray(XS), jnp.asarray(YS), m=M, r=R))
    samples = estimates("hybrid", orthogonal=False, seed=2)
    for index in (0, 5):  # theta = 0 and theta = pi, |x| = |y|
        assert closed[index] < 1e-10
        truth = exact("hybrid")[index]
        assert np.max(np.abs(samples[:, index] - truth)) < 2e-5 * truth  # float32 rounding only
    # ...but not in between, and not for the exp estimator at theta = 0.
    assert closed[2] > 1e-3
    assert float(ft.closed_form_mse("exp", XS[0], YS[0], m=M)) > 1e-2


def test_angular_estimator_is_exact_at_zero_and_pi():
    samples = estimates("angular", orthogonal=False)
    for index, truth in ((0, 1.0), (5, -1.0)):
        assert np.ptp(samples[:, index]) == 0.0  # zero variance: every draw gives one value
        assert abs(samples[0, index] - truth) < 1e-6
    assert samples[:, 2].std() > 0.1


def test_orthogonal_draws_are_block_orthogonal_with_gaussian_norms():
    rows = ft.gaussian_directions(jax.random.PRNGKey(3), 2 * D + 1, D, orthogonal=True)
    first_block = np.asarray(rows[:D])
    gram = first_block @ first_block.T
    np.testing.assert_allclose(gram - np.diag(np.diag(gram)), 0, atol=1e-4)
    # Squared norms are chi-squared with D degrees of freedom: mean D, variance 2D.
    many = jax.vmap(lambda k: ft.gaussian_directions(k, D, D, orthogonal=True))(
        jax.random.split(jax.random.PRNGKey(4), 20_000)
    )
    sq_norms = np.asarray(jnp.sum(many**2, -1)).ravel()
    assert abs(sq_norms.mean() - D) < Z * math.sqrt(2 * D / sq_norms.size)
    # the sample variance's standard error: sqrt((mu4 - sigma^4) / n), chi-squared's central
    # fourth moment mu4 = 12 D (D + 4)
    assert abs(sq_norms.var() - 2 * D) < Z * math.sqrt((12 * D * (D + 4) - (2 * D) ** 2) / sq_norms.size)


def mse_gain_z(orthogonal: bool) -> np.ndarray:
    """Per point: (iid MSE - MSE of the ``orthogonal`` draws, another seed) over its standard
    error, from the squared errors' spread over the draws."""
    iid = (estimates("exp", orthogonal=False, seed=5) - exact("exp")) ** 2
    other = (estimates("exp", orthogonal=orthogonal, seed=6) - exact("exp")) ** 2
    error = np.sqrt(iid.var(0) / len(iid) + other.var(0) / len(other))
    return (iid.mean(0) - other.mean(0)) / np.maximum(error, 1e-30)


def test_orthogonal_draws_lower_the_error():
    """Orthogonal draws are nowhere worse than iid ones (by ``Z`` standard errors) and better
    by more than ``Z`` at some points; iid draws of another seed, in their place, are not."""
    gain = mse_gain_z(orthogonal=True)
    assert gain.min() > -Z and gain.max() > Z, gain
    assert np.abs(mse_gain_z(orthogonal=False)).max() < Z


def test_feature_counts_and_shapes():
    x = jnp.ones((7, 3, D))
    for kind in ft.KINDS:
        proj = ft.draw_projections(jax.random.PRNGKey(0), kind, m=M, d=D, r=R)
        out = ft.feature_map(kind, x, proj, role="key")
        assert out.shape == (7, 3, ft.feature_count(kind, m=M, d=D, r=R))
    assert ft.feature_count("hybrid", m=10, r=5) == 180


def test_exp_features_do_not_overflow_at_norm_ten():
    x = 10.0 * jax.random.normal(jax.random.PRNGKey(1), (64, D))
    x = 10.0 * x / jnp.linalg.norm(x, axis=-1, keepdims=True)
    proj = ft.draw_projections(jax.random.PRNGKey(2), "exp", m=M, d=D)
    feats = ft.feature_map("exp", x, proj, role="query")
    assert bool(jnp.all(jnp.isfinite(feats)))


@pytest.mark.parametrize("kind", ["exp", "trig", "hybrid"])
def test_stabilizer_only_rescales_scores(kind):
    """Stabilised float32 scores are the float64 unstabilised ones times one positive constant."""
    keys = jax.random.split(jax.random.PRNGKey(11), 3)
    q = 1.5 * jax.random.normal(keys[0], (50, D)) / math.sqrt(D)
    k = 1.5 * jax.random.normal(keys[1], (50, D)) / math.sqrt(D)
    proj = ft.draw_projections(keys[2], kind, m=M, d=D, r=R)
    k_features = np.asarray(ft.feature_map(kind, k, proj, role="key", stabilize=True), np.float64)
    q_features = np.asarray(ft.feature_map(kind, q, proj, role="query", stabilize=True), np.float64)
    stable = np.asarray(
        ft.feature_map(kind, k, proj, role="key", stabilize=True)
        @ ft.feature_map(kind, q, proj, role="query", stabilize=True).sum(0)
    )
    with jax.enable_x64(True):
        proj64 = jax.tree.map(lambda a: jnp.asarray(a, jnp.float64), proj)
        q64, k64 = jnp.asarray(q, jnp.float64), jnp.asarray(k, jnp.float64)
        plain = np.asarray(
            ft.feature_map(kind, k64, proj64, role="key") @ ft.feature_map(kind, q64, proj64, role="query").sum(0)
        )
    ratio = stable / plain
    assert np.all(ratio > 0)
    # float32 rounding, bounded with slack by the textbook bound for a sum of products (n eps
    # times the sum of the terms' magnitudes, n the longest chain of roundings a score goes
    # through): each feature is a d-term dot product, a shift and one exp, cos or sin (D + 3;
    # an exp or a sine turns its argument's absolute rounding into a relative one of the same
    # size, and the arguments here are of order one), summed over the queries, then over the
    # features. The errors measured are 0.07-3% of this bound.
    chain = D + 3 + q.shape[0] + k_features.shape[1]
    magnitude = np.abs(k_features) @ np.abs(q_features).sum(0)
    relative = chain * np.finfo(np.float32).eps * magnitude / np.abs(stable)
    np.testing.assert_array_less(np.abs(ratio / ratio[0] - 1), relative + relative[0])


@pytest.mark.parametrize("kind", ["exp", "trig", "hybrid"])
def test_stabilized_top_l_matches_float64_at_norm_ten(kind):
    keys = jax.random.split(jax.random.PRNGKey(12), 3)

    def on_sphere(key, n):
        u = jax.random.normal(key, (n, D))
        return 10.0 * u / jnp.linalg.norm(u, axis=-1, keepdims=True)

    q, k = on_sphere(keys[0], 40), on_sphere(keys[1], 40)
    proj = ft.draw_projections(keys[2], kind, m=M, d=D, r=R)
    stable = ft.feature_map(kind, k, proj, role="key", stabilize=True) @ ft.feature_map(
        kind, q, proj, role="query", stabilize=True
    ).sum(0)
    assert bool(jnp.all(jnp.isfinite(stable)))
    with jax.enable_x64(True):
        proj64 = jax.tree.map(lambda a: jnp.asarray(a, jnp.float64), proj)
        q64, k64 = jnp.asarray(q, jnp.float64), jnp.asarray(k, jnp.float64)
        plain = ft.feature_map(kind, k64, proj64, role="key") @ ft.feature_map(kind, q64, proj64, role="query").sum(0)
        assert bool(jnp.all(jnp.isfinite(plain)))
    top = 5
    assert list(np.argsort(-np.asarray(stable))[:top]) == list(np.argsort(-np.asarray(plain))[:top])


def test_bad_arguments_raise_clear_errors():
    key = jax.random.PRNGKey(0)
    with pytest.raises(
        ValueError, match="feature map kind must be one of relu, exp, trig, hybrid, angular, got 'favor'"
    ):
        ft.draw_projections(key, "favor", m=4, d=4)
    with pytest.raises(ValueError, match="m must be an int >= 1"):
        ft.draw_projections(key, "exp", m=0, d=4)
    with pytest.raises(ValueError, match="r must be an int >= 1"):
        ft.draw_projections(key, "hybrid", m=4, d=4, r=-1)
    proj = ft.draw_projections(key, "exp", m=4, d=4)
    with pytest.raises(ValueError, match="role must be one of query, key"):
        ft.feature_map("exp", jnp.ones(4), proj, role="value")
    with pytest.raises(ValueError, match="lack the matrices"):
        ft.feature_map("hybrid", jnp.ones(4), proj, role="query")
    with pytest.raises(ValueError, match="closed_form_mse's kind must be one of exp, trig, hybrid"):
        ft.closed_form_mse("angular", jnp.ones(4), jnp.ones(4), m=4)


def test_sincos_matches_float64_sine_and_cosine():
    x = np.linspace(-1000.0, 1000.0, 2_000_001, dtype=np.float32)
    sin, cos = jax.jit(ft.sincos)(jnp.asarray(x))
    np.testing.assert_allclose(np.asarray(sin), np.sin(x.astype(np.float64)), atol=2e-7, rtol=0)
    np.testing.assert_allclose(np.asarray(cos), np.cos(x.astype(np.float64)), atol=2e-7, rtol=0)
