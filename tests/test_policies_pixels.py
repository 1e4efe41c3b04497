"""IAP, brute-force (AttentionAgent) and CNN pixel policies: shapes, selection, projections, errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from iap_mjx import policies
from iap_mjx.attention import extract_patches
from iap_mjx.policies.base import param_count

SHAPE = (20, 20, 3)


def images(batch, seed=0):
    return jax.random.uniform(jax.random.PRNGKey(seed), (batch, *SHAPE))


@pytest.mark.parametrize(
    "options",
    [
        {"kernel": "hybrid", "m": 10, "r": 5},
        {"kernel": "relu"},
        {"kernel": "brute", "row_normalize": True},
        {"kernel": "hybrid", "controller": "mlp", "hidden_sizes": [8], "with_patches": True},
    ],
)
def test_iap_policy_acts_under_jit_and_vmap(options):
    policy = policies.make("iap", SHAPE, 6, patch_size=4, top_l=5, **options)
    params = policy.init(jax.random.PRNGKey(1))
    state = policy.initial_state(jax.random.PRNGKey(2))
    actions, _ = jax.jit(jax.vmap(policy.apply, in_axes=(None, 0, None)))(params, images(4), state)
    assert actions.shape == (4, 6)
    assert bool(jnp.all(jnp.abs(actions) <= 1))
    features_per_patch = 2 + (48 if options.get("with_patches") else 0)
    hidden = options.get("hidden_sizes", [])
    expected = sum(a * b + b for a, b in zip([5 * features_per_patch, *hidden], [*hidden, 6]))
    assert param_count(params) == 2 * 48 * 4 + expected


def test_iap_policy_feeds_the_selected_patch_centres():
    policy = policies.make("iap", SHAPE, 2, patch_size=4, top_l=3, with_patches=True)
    params = policy.init(jax.random.PRNGKey(0))
    state = policy.initial_state(jax.random.PRNGKey(0))
    projections, _ = state
    image = images(1)[0]
    features, selection = policy.features(params, image, projections)
    patches, centres = extract_patches(image, 4)
    np.testing.assert_array_equal(features[:6], centres[selection.indices].reshape(-1))
    np.testing.assert_array_equal(features[6:], patches[selection.indices].reshape(-1))
    # The controller is affine in these features: the action is tanh(features @ w + b).
    action, _ = policy.apply(params, image, state)
    layer = params["controller"][0]
    np.testing.assert_allclose(action, jnp.tanh(features @ layer["w"] + layer["b"]), rtol=1e-5)


def test_lstm_controller_carries_memory_across_steps():
    policy = policies.make("iap", SHAPE, 2, patch_size=4, top_l=3, controller="lstm", hidden_sizes=[5])
    params = policy.init(jax.random.PRNGKey(0))
    start = policy.initial_state(jax.random.PRNGKey(1))
    image = images(1)[0]
    first, state = jax.jit(policy.apply)(params, image, start)
    second, _ = jax.jit(policy.apply)(params, image, state)
    assert first.shape == (2,) and not np.allclose(first, second)  # same input, different memory
    np.testing.assert_array_equal(np.asarray(start[1][0]), np.zeros(5))
    assert param_count(params["controller"]) == (6 + 5) * 20 + 20 + 5 * 2 + 2
    np.testing.assert_array_equal(
        policy.select(params, image, state).indices, policy.select(params, image, start).indices
    )


def test_projections_are_fixed_unless_redrawn():
    fixed = policies.make("iap", SHAPE, 2, patch_size=4, top_l=3)
    (a, _), (b, _) = fixed.initial_state(jax.random.PRNGKey(1)), fixed.initial_state(jax.random.PRNGKey(2))
    np.testing.assert_array_equal(a.omega, b.omega)
    redrawn = policies.make("iap", SHAPE, 2, patch_size=4, top_l=3, redraw_projections=True)
    (a, _), (b, _) = redrawn.initial_state(jax.random.PRNGKey(1)), redrawn.initial_state(jax.random.PRNGKey(2))
    assert not np.allclose(a.omega, b.omega)


def test_pixels_plus_state_observations():
    shape = {"pixels": SHAPE, "state": (7,)}
    for kind, options in (("iap", {"patch_size": 4, "top_l": 3}), ("convnet", {"strides": (2, 2, 1)})):
        policy = policies.make(kind, shape, 2, **options)
        params = policy.init(jax.random.PRNGKey(0))
        obs = {"pixels": images(1)[0], "state": jnp.arange(7.0)}
        action, _ = jax.jit(policy.apply)(params, obs, policy.initial_state(jax.random.PRNGKey(0)))
        assert action.shape == (2,)
        moved, _ = policy.apply(params, {**obs, "state": obs["state"] + 1}, policy.initial_state(jax.random.PRNGKey(0)))
        assert not np.allclose(action, moved)  # the state sensors reach the action


def test_bad_pixel_policy_settings_fail_early():
    with pytest.raises(
        ValueError, match=r"AttentionConfig\.top_l must be at most the number of patches L = 25 .*, got 30\."
    ):
        policies.make("iap", SHAPE, 2, patch_size=4, top_l=30)
    with pytest.raises(ValueError, match="do not tile"):
        policies.make("iap", SHAPE, 2, patch_size=3)
    with pytest.raises(ValueError, match="needs \\(H, W, C\\) observations"):
        policies.make("iap", (17,), 2)
    with pytest.raises(ValueError, match="IAPPolicy.controller"):
        policies.make("iap", SHAPE, 2, patch_size=4, top_l=3, controller="gru")
    with pytest.raises(ValueError, match="IAPPolicy.hidden_sizes"):
        policies.make("iap", SHAPE, 2, patch_size=4, top_l=3, controller="mlp", hidden_sizes=32)
    with pytest.raises(ValueError, match="IAPPolicy.hidden_sizes"):
        policies.make("iap", SHAPE, 2, patch_size=4, top_l=3, controller="lstm", hidden_sizes=())
    with pytest.raises(ValueError, match="ConvNetPolicy.channels"):
        policies.make("convnet", SHAPE, 2, channels=())


def _lstm_reference(params, features, hidden, cell):
    """The LSTM equations in numpy (gates in the order input, forget, candidate, output)."""
    w, b = np.asarray(params["cell"]["w"], np.float64), np.asarray(params["cell"]["b"], np.float64)
    gates = np.concatenate([features, hidden]) @ w + b
    i, f, g, o = np.split(gates, 4)
    sigmoid = lambda x: 1 / (1 + np.exp(-x))  # noqa: E731
    cell = sigmoid(f) * cell + sigmoid(i) * np.tanh(g)
    hidden = sigmoid(o) * np.tanh(cell)
    out = params["out"][0]
    return np.tanh(hidden @ np.asarray(out["w"], np.float64) + np.asarray(out["b"], np.float64)), hidden, cell


def test_lstm_controller_is_the_lstm_equations():
    from iap_mjx.policies.controller import Controller

    head = Controller("lstm", 7, 3, (5,))
    params = head.init(jax.random.PRNGKey(3))
    carry, hidden, cell = head.initial_carry(), np.zeros(5), np.zeros(5)
    for t in range(4):
        features = np.asarray(jax.random.normal(jax.random.PRNGKey(10 + t), (7,)))
        action, carry = jax.jit(head.apply)(params, features, carry)
        expected, hidden, cell = _lstm_reference(params, features, hidden, cell)
        np.testing.assert_allclose(action, expected, rtol=0, atol=1e-5)
        np.testing.assert_allclose(carry[0], hidden, rtol=0, atol=1e-5)


def _conv_same_reference(x, w, b, stride):
    """XLA's "SAME" strided convolution in numpy: ``ceil(n / stride)`` outputs per axis, the
    padding split with the smaller half first."""
    f = w.shape[0]
    out_shape = [-(-n // stride) for n in x.shape[:2]]
    pads = [max((o - 1) * stride + f - n, 0) for o, n in zip(out_shape, x.shape[:2])]
    padded = np.pad(x, ((pads[0] // 2, pads[0] - pads[0] // 2), (pads[1] // 2, pads[1] - pads[1] // 2), (0, 0)))
    out = np.zeros((*out_shape, w.shape[-1]))
    for i in range(out_shape[0]):
        for j in range(out_shape[1]):
            window = padded[i * stride : i * stride + f, j * stride : j * stride + f]
            out[i, j] = np.tensordot(window, w, axes=3) + b
    return out


def test_convnet_policy_is_convolutions_pool_embedding_and_the_iap_controller():
    """The baseline's features against a numpy convolution, ReLU and max pool; its controller is
    IAP's (the same ``Controller``), its parameter count the sum of its layers."""
    shape = (24, 40, 3)
    policy = policies.make(
        "convnet", shape, 2, channels=[4, 6], strides=[2, 3], pool=2, embedding_size=5, hidden_sizes=[7]
    )
    params = policy.init(jax.random.PRNGKey(0))
    image = np.asarray(jax.random.uniform(jax.random.PRNGKey(1), shape))
    x = image
    for layer, stride in zip(params["conv"], (2, 3)):
        x = np.maximum(_conv_same_reference(x, np.asarray(layer["w"]), np.asarray(layer["b"]), stride), 0)
    rows, cols = x.shape[0] // 2, x.shape[1] // 2  # 24x40 -> 12x20 -> 4x7 -> pooled 2x3
    pooled = x[: 2 * rows, : 2 * cols].reshape(rows, 2, cols, 2, -1).max(axis=(1, 3))
    np.testing.assert_allclose(policy.body.embed(params["conv"], jnp.asarray(image)), pooled.ravel(), atol=1e-5)
    embed = params["embed"][0]
    features = np.tanh(pooled.ravel() @ np.asarray(embed["w"]) + np.asarray(embed["b"]))
    action, carry = jax.jit(policy.apply)(params, jnp.asarray(image), policy.initial_state(None))
    expected, hidden, _ = _lstm_reference(params["controller"], features, np.zeros(7), np.zeros(7))
    np.testing.assert_allclose(action, expected, atol=1e-5)
    np.testing.assert_allclose(carry[0], hidden, atol=1e-5)
    iap = policies.make("iap", SHAPE, 2, patch_size=4, top_l=3, controller="lstm", hidden_sizes=(7,))
    assert type(policy.head) is type(iap.head) and policy.head.kind == iap.head.kind == "lstm"
    conv = (27 * 4 + 4) + (9 * 4 * 6 + 6)
    assert param_count(params) == conv + (2 * 3 * 6 * 5 + 5) + ((5 + 7) * 28 + 28) + (7 * 2 + 2)
    with pytest.raises(ValueError, match="ConvNetPolicy.controller"):
        policies.make("convnet", shape, 2, strides=(2, 2, 1), controller="gru")
    with pytest.raises(ValueError, match="shrinks to nothing"):
        policies.make("convnet", (8, 8, 3), 2, strides=(4, 4, 2))


def test_a_state_observation_is_refused_naming_every_pixel_mode():
    from iap_mjx.configs.env import PIXEL_MODES
    from iap_mjx.policies.observations import pixel_shape

    with pytest.raises(ValueError, match=r"needs \(H, W, C\) observations, got \(17,\)") as error:
        pixel_shape((17,))
    assert all(f"'{mode}'" in str(error.value) for mode in PIXEL_MODES), error.value
    assert pixel_shape({"pixels": (24, 32, 1), "state": (17,)}) == ((24, 32, 1), 17)
