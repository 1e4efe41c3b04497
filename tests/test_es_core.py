"""The ES core against closed forms: ranks, antithetic structure, the gradient estimate on a
quadratic, weight decay, Adam's first step, and the evosax adapter's direction."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
import scipy.stats

from iap_mjx.configs import ESConfig, training
from iap_mjx.es.components import make_optimizer
from iap_mjx.es.shaping import SHAPINGS, centred_ranks, identity, nan_to_worst, z_scores
from iap_mjx.es.strategy import EvosaxStrategy, OpenES, antithetic_noise, estimate_gradient


def test_centred_ranks_without_ties_are_the_ordinal_ranks_to_the_bit():
    """Tie-free returns (every continuous reward) shape as they did when ties went by position,
    compiled, to the bit: the runs trained then stay the runs trained now."""
    fitness = jnp.asarray(np.random.default_rng(0).normal(size=37).astype(np.float32))
    want = (scipy.stats.rankdata(np.asarray(fitness), method="ordinal") - 1) / 36 - 0.5
    np.testing.assert_allclose(centred_ranks(fitness), want, atol=1e-7)

    @jax.jit
    def by_position(f):  # ordinal ranks, ties by position: the shaping before ties were shared
        return jnp.argsort(jnp.argsort(f, stable=True), stable=True).astype(jnp.float32) / (f.shape[0] - 1) - 0.5

    np.testing.assert_array_equal(jax.jit(centred_ranks)(fitness), by_position(fitness))


def test_tied_members_share_scipys_average_rank():
    # sparse returns as reacher's: whole steps, most members none, a NaN among them
    fitness = np.random.default_rng(1).choice([0.0, 0.0, 0.0, 3.0, 7.0, 12.0], size=64).astype(np.float32)
    fitness[5] = np.nan
    rankable = np.where(np.isnan(fitness), -np.inf, fitness)
    want = (scipy.stats.rankdata(rankable, method="average") - 1) / 63 - 0.5
    np.testing.assert_allclose(centred_ranks(jnp.asarray(fitness)), want, atol=1e-7)


def test_a_population_tied_throughout_takes_no_step():
    """Ranked by position, 64 members all scoring 0 would step along ``-sum(eps)`` as far as an
    informative iteration does; tied pairs must cancel instead."""
    eps = antithetic_noise(jax.random.PRNGKey(0), 64, 5)
    for fitness in (jnp.zeros(64), jnp.zeros(64).at[3].set(1.0).at[35].set(1.0)):  # all tied; one pair apart, tied
        grad = estimate_gradient(eps, centred_ranks(fitness), 0.1)
        np.testing.assert_allclose(grad, 0.0, atol=1e-6)


def test_nan_fitness_ranks_and_scores_lowest():
    fitness = jnp.array([1.0, jnp.nan, -3.0, 2.0])
    ranks = centred_ranks(fitness)
    assert float(ranks[1]) == -0.5 and float(ranks[3]) == 0.5
    for shaping in (z_scores, identity):
        shaped = shaping(fitness)
        assert np.all(np.isfinite(shaped))
        assert float(shaped[1]) == float(jnp.min(shaped))


def test_nan_to_worst_puts_non_finite_entries_below_every_finite_one():
    values = jnp.array([1.0, jnp.nan, -3.0, jnp.inf, 2.0])
    for margin in (0.0, 1.0):
        expected = [1.0, -3.0 - margin, -3.0, -3.0 - margin, 2.0]
        np.testing.assert_array_equal(np.asarray(nan_to_worst(values, margin)), expected)
    # z-scores of the finite entries as their closed form: mean and (population) std over them
    finite = np.array([1.0, -3.0, 5.0])  # a mean off 0: a NaN counted as 0 would move the std
    shaped = np.asarray(z_scores(jnp.array([1.0, jnp.nan, -3.0, 5.0])))
    np.testing.assert_allclose(shaped[[0, 2, 3]], (finite - finite.mean()) / finite.std(), rtol=1e-6)
    assert shaped[1] == shaped.min()


def test_each_shaping_name_gives_the_shaping_it_names():
    """``es.shaping``'s names live in ``configs.training``; ``es`` keys its table by them, and a
    name paired with the wrong function would still run: each is checked by what it computes
    (ranks in [-0.5, 0.5], zero mean and unit std, the raw values)."""
    assert set(SHAPINGS) == set(training.SHAPING_NAMES)
    fitness = jnp.array([3.0, 1.0, 2.0])
    np.testing.assert_allclose(SHAPINGS["centred_rank"](fitness), [0.5, -0.5, 0.0])
    np.testing.assert_allclose(
        SHAPINGS["z_score"](fitness), (np.array([3.0, 1.0, 2.0]) - 2.0) / np.sqrt(2 / 3), rtol=1e-6
    )
    np.testing.assert_array_equal(SHAPINGS["identity"](fitness), fitness)


def test_a_table_for_the_config_names_must_hold_each_name_once():
    table = {"a": 1, "b": 2}
    assert training.one_per_name(("b", "a"), table) is table
    for names in (("a",), ("a", "b", "c")):
        with pytest.raises(ImportError, match="holds"):
            training.one_per_name(names, table)


def test_each_optimizer_name_gives_the_optimizer_it_names():
    """As the shapings: ``es.optimizer``'s names index a table built from them. Two steps on a
    constant gradient ``g`` at learning rate ``lr`` tell them apart: sgd moves ``-lr g`` twice,
    momentum (0.9) ``-lr g`` then ``-1.9 lr g``, Adam ``-lr sign(g)`` (its bias-corrected first
    step) then the same again (to float32's rounding of the corrections: 1e-5 relative; the
    three differ by 50% or more)."""
    grad, lr = jnp.array([2.0, -0.5]), 0.1
    expected = {
        "sgd": (-lr * grad, -lr * grad),
        "momentum": (-lr * grad, -1.9 * lr * grad),
        "adam": (-lr * jnp.sign(grad), -lr * jnp.sign(grad)),
    }
    assert set(expected) == set(training.OPTIMIZER_NAMES)
    for name, (first, second) in expected.items():
        optimizer = make_optimizer(ESConfig(optimizer=name, learning_rate=lr))
        params = jnp.zeros(2)
        state = optimizer.init(params)
        step_one, state = optimizer.update(grad, state, params)
        step_two, _ = optimizer.update(grad, state, params)
        np.testing.assert_allclose(step_one, first, rtol=1e-4, err_msg=name)
        np.testing.assert_allclose(step_two, second, rtol=1e-4, err_msg=name)


def test_antithetic_noise_is_mirrored_and_population_symmetric():
    noise = antithetic_noise(jax.random.PRNGKey(0), 10, 3)
    np.testing.assert_array_equal(noise[:5], -noise[5:])
    strategy = OpenES(population_size=10, sigma=0.5)
    mean = jnp.array([1.0, -2.0, 3.0])
    population, _ = strategy.ask(jax.random.PRNGKey(1), strategy.init(None, mean))
    np.testing.assert_allclose(population[:5] + population[5:], jnp.tile(2 * mean, (5, 1)), atol=1e-6)


def _quadratic(num_dims: int):
    rng = np.random.default_rng(1)
    basis = rng.normal(size=(num_dims, num_dims))
    hessian = jnp.asarray(basis @ basis.T / num_dims + np.eye(num_dims), jnp.float32)
    centre = jnp.asarray(rng.normal(size=num_dims), jnp.float32)

    def objective(x):
        return -0.5 * (x - centre) @ hessian @ (x - centre)

    return objective, centre, hessian


def _one_step(strategy, objective, mean, key):
    """Returns the update ``new_mean - mean`` and the population of one ask/tell."""
    state = strategy.init(None, mean)
    population, state = strategy.ask(key, state)
    fitness = jax.vmap(objective)(population)
    new_state = strategy.tell(key, population, fitness, state)
    return new_state.mean - mean, population


def test_antithetic_gradient_estimate_matches_true_gradient_on_quadratic():
    # On a quadratic, (F(x + s z) - F(x - s z)) / (2 s) = g.z exactly, so the antithetic
    # estimate is the mean of (g.z) z over P/2 pairs: unbiased, per-coordinate variance
    # (|g|^2 + g_k^2) / (P/2).
    objective, _, _ = _quadratic(6)
    mean = jnp.linspace(-1.0, 1.0, 6)
    true_grad = jax.grad(objective)(mean)
    population_size = 4000
    strategy = OpenES(population_size, sigma=0.05, optimizer=optax.sgd(1.0), shaping=identity)
    update, _ = _one_step(strategy, objective, mean, jax.random.PRNGKey(0))
    std = jnp.sqrt((jnp.sum(true_grad**2) + true_grad**2) / (population_size / 2))
    z = np.asarray((update - true_grad) / std)
    assert np.all(np.abs(z) < 4.5), z


def test_plain_gradient_estimate_is_unbiased_on_quadratic():
    # Without mirroring the estimate is the sample mean of F(x + s e) e / s: check it against
    # the true gradient with the tolerance of that sample mean's own standard error. The
    # population is large enough that the tolerance is below half of every coordinate of the
    # gradient: the same check on half the update must fail (a scale error is caught).
    objective, _, _ = _quadratic(4)
    mean = jnp.array([0.3, -0.2, 0.5, 0.1])
    true_grad = jax.grad(objective)(mean)
    sigma = 0.1
    strategy = OpenES(400_000, sigma=sigma, optimizer=optax.sgd(1.0), shaping=identity, antithetic=False)
    update, population = _one_step(strategy, objective, mean, jax.random.PRNGKey(2))
    eps = (population - mean) / sigma
    terms = jax.vmap(objective)(population)[:, None] * eps / sigma
    stderr = jnp.std(terms, axis=0) / jnp.sqrt(terms.shape[0])
    # the update is that sample mean, up to float32 sums taken in another order: far below
    # the statistical tolerance
    np.testing.assert_allclose(update, jnp.mean(terms, axis=0), rtol=0, atol=0.01 * float(jnp.min(stderr)))
    z = np.asarray((update - true_grad) / stderr)
    assert np.all(np.abs(z) < 4.5), z
    z_half = np.asarray((0.5 * update - true_grad) / stderr)
    assert np.any(np.abs(z_half) > 4.5), z_half


def test_weight_decay_alone_pulls_mean_to_zero():
    mean = jnp.array([2.0, -4.0])
    strategy = OpenES(8, sigma=0.1, optimizer=optax.sgd(0.5), weight_decay=0.1, shaping=identity)
    state = strategy.init(None, mean)
    population, state = strategy.ask(jax.random.PRNGKey(0), state)
    flat_fitness = jnp.zeros(8)  # no signal: only the decay term moves the mean
    new_state = strategy.tell(None, population, flat_fitness, state)
    np.testing.assert_allclose(new_state.mean, mean * (1 - 0.5 * 0.1), rtol=1e-6)


def test_adam_first_step_is_learning_rate_times_sign_of_estimate():
    objective, _, _ = _quadratic(5)
    mean = jnp.ones(5)
    key = jax.random.PRNGKey(4)
    sgd = OpenES(64, sigma=0.05, optimizer=optax.sgd(1.0))
    adam = OpenES(64, sigma=0.05, optimizer=optax.adam(0.01))
    estimate, _ = _one_step(sgd, objective, mean, key)
    step, _ = _one_step(adam, objective, mean, key)
    np.testing.assert_allclose(step, 0.01 * np.sign(estimate), rtol=1e-4)


def test_centred_rank_update_is_invariant_to_monotone_fitness_transforms():
    objective, _, _ = _quadratic(3)
    strategy = OpenES(16, sigma=0.1)
    state = strategy.init(None, jnp.zeros(3))
    population, state = strategy.ask(jax.random.PRNGKey(5), state)
    fitness = jax.vmap(objective)(population)
    a = strategy.tell(None, population, fitness, state).mean
    b = strategy.tell(None, population, jnp.exp(fitness / 10) * 3 + 7, state).mean
    np.testing.assert_array_equal(a, b)


def test_sigma_schedule_is_applied_per_iteration():
    schedule = optax.linear_schedule(0.2, 0.1, 10)
    strategy = OpenES(4, sigma=schedule, optimizer=optax.sgd(0.0))
    state = strategy.init(None, jnp.zeros(1))
    for iteration in (0, 5, 10):
        state = state.replace(iteration=jnp.asarray(iteration, jnp.int32))
        population, _ = strategy.ask(jax.random.PRNGKey(0), state)
        noise = antithetic_noise(jax.random.PRNGKey(0), 4, 1)
        np.testing.assert_allclose(population, schedule(iteration) * noise, rtol=1e-6)


def test_odd_antithetic_population_is_rejected():
    with pytest.raises(ValueError, match="population_size"):
        OpenES(5)


@pytest.mark.parametrize("name", ["CMA_ES", "SNES"])
def test_evosax_adapter_maximises(name):
    # evosax minimises: the adapter must negate, so the mean approaches the maximiser.
    objective, centre, _ = _quadratic(4)
    strategy = EvosaxStrategy(name, population_size=16, num_dims=4, sigma=0.3)
    state = strategy.init(jax.random.PRNGKey(0), jnp.zeros(4))

    @jax.jit
    def step(state, key):
        ask_key, tell_key = jax.random.split(key)
        population, state = strategy.ask(ask_key, state)
        return strategy.tell(tell_key, population, jax.vmap(objective)(population), state), None

    start = float(objective(strategy.mean(state)))
    state, _ = jax.lax.scan(step, state, jax.random.split(jax.random.PRNGKey(1), 60))
    end = float(objective(strategy.mean(state)))
    assert end > 0.5 * start  # start < 0: the gap to the optimum (0) more than halved
    assert float(jnp.linalg.norm(strategy.mean(state) - centre)) < float(jnp.linalg.norm(centre))


@pytest.mark.parametrize("name", training.EVOSAX_STRATEGIES)
def test_every_listed_evosax_strategy_asks_one_population_around_one_mean(name):
    """Every name ``es.strategy`` takes builds through the adapter and gives what training
    reads: ``(P, D)`` members and a ``(D,)`` mean (traced, not compiled)."""
    sample = lambda key: jax.random.normal(key, (3,))  # noqa: E731  (RandomSearch's one member)
    options = (("sampling_fn", sample),) if name == "RandomSearch" else ()
    strategy = EvosaxStrategy(name, population_size=6, num_dims=3, options=options)
    state = jax.eval_shape(strategy.init, jax.random.PRNGKey(0), jnp.zeros(3))
    population, _ = jax.eval_shape(strategy.ask, jax.random.PRNGKey(1), state)
    assert population.shape == (6, 3)
    assert jax.eval_shape(strategy.mean, state).shape == (3,)


@pytest.mark.parametrize(
    ("name", "options", "match"),
    [
        ("SV_CMA_ES", (("num_populations", 2),), "one population around one mean"),
        ("SimpleGA", (), "one population around one mean"),
        ("RandomSearch", (), "es.evosax_options .*sampling_fn"),
        ("CMA_ES", (("no_such_argument", 1),), "es.evosax_options .*no_such_argument"),
    ],
)
def test_unusable_evosax_strategy_or_options_are_refused_clearly(name, options, match):
    with pytest.raises(ValueError, match=match):
        EvosaxStrategy(name, population_size=4, num_dims=2, options=options)


def test_unknown_evosax_strategy_lists_valid_names():
    with pytest.raises(ValueError, match="CMA_ES"):
        EvosaxStrategy("NoSuchES", population_size=4, num_dims=2)


def test_observation_statistics_merge_equals_whole_batch_moments():
    from iap_mjx.es.normalizer import init_stats, normalize, update_stats

    rng = np.random.default_rng(3)
    batches = [rng.normal(loc=2.0, scale=3.0, size=(n, 4)) for n in (5, 40, 1, 17)]
    stats = init_stats(4)
    for batch in batches:
        stats = update_stats(stats, jnp.float32(len(batch)), jnp.asarray(batch.sum(0)), jnp.asarray((batch**2).sum(0)))
    stats = update_stats(stats, jnp.float32(0), jnp.zeros(4), jnp.zeros(4))  # empty: no-op
    everything = np.concatenate(batches)
    np.testing.assert_allclose(stats.count, len(everything))
    np.testing.assert_allclose(stats.mean, everything.mean(0), rtol=1e-5)
    np.testing.assert_allclose(stats.var, everything.var(0), rtol=1e-4)
    z = normalize(stats, jnp.asarray(everything[0]))
    np.testing.assert_allclose(z, (everything[0] - everything.mean(0)) / everything.std(0), rtol=1e-3)


@pytest.mark.parametrize(
    ("kind", "shape", "valid"),
    [
        ("linear", (17,), "zero_init"),
        ("iap", (16, 16, 3), "top_l"),
        ("convnet", (16, 16, 3), "channels"),
        ("pmtg", (40,), "residual_range"),
        ("hierarchical", {"pixels": (24, 32, 3), "state": (40,)}, "duration_range"),
    ],
)
def test_misspelt_policy_option_names_the_valid_ones(kind, shape, valid):
    from iap_mjx import policies

    with pytest.raises(
        ValueError, match=rf"policy\.options \['top_ll'\] do not fit policy '{kind}'; valid: \[.*'{valid}'"
    ):
        policies.make(kind, shape, 6, top_ll=5)


def test_policies_shapes_counts_and_registry():
    from iap_mjx import policies

    linear = policies.make("linear", (17,), 6)
    mlp = policies.make("mlp", (17,), 6, hidden_sizes=(32, 16))
    assert policies.param_count(linear.init(jax.random.PRNGKey(0))) == 17 * 6 + 6
    mlp_params = mlp.init(jax.random.PRNGKey(0))
    assert policies.param_count(mlp_params) == 17 * 32 + 32 + 32 * 16 + 16 + 16 * 6 + 6
    action, state = mlp.apply(mlp_params, 100 * jnp.ones(17), mlp.initial_state(None))
    assert action.shape == (6,) and state == () and float(jnp.max(jnp.abs(action))) <= 1.0
    with pytest.raises(ValueError, match=r"policy\.kind must be one of "):
        policies.make("transformer", (17,), 6)
    with pytest.raises(
        ValueError,
        match=r"policy\.options \['width'\] do not fit policy 'mlp'; valid: \['activation', 'hidden_sizes'\]",
    ):
        policies.make("mlp", (17,), 6, width=3)
    with pytest.raises(ValueError, match="hidden_sizes"):
        policies.make("mlp", (17,), 6, hidden_sizes=(0,))
