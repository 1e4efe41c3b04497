"""The hierarchical quadruped policy: the countdown that holds the high level's command (under
``vmap``, against schedules worked out by hand), the duration's mapping, the blind control, the
paper's CNN high level and its size, the factory's checks, a low level from a file, and the
shipped turn run as that file."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from iap_mjx import policies
from iap_mjx.es.normalizer import ObsStats, normalize
from iap_mjx.policies.convnet import ConvNet
from iap_mjx.policies.hierarchical import (
    AttentiveHierarchicalPolicy,
    HierarchicalPolicy,
    commanded_low_level,
    duration_steps,
    fold_normalisation,
)
from iap_mjx.policies.pmtg import PMTGPolicy, PMTGState

OBS = {"pixels": (24, 32, 3), "state": (17,)}


@dataclasses.dataclass(frozen=True)
class ScriptedHighLevel:
    """A high level that reads its output off the image: ``pixels[0, 0, 0]`` is the duration
    in ``[-1, 1]``, ``pixels[0, 0, 1]`` every latent entry. It has no parameters."""

    image_shape: tuple[int, int, int] = (2, 2, 3)
    output_size: int = 3

    def init(self, key):
        return {}

    def initial_state(self, key):
        return ()

    def apply(self, params, obs, state):
        return jnp.concatenate([obs[0, 0, :1], jnp.full((self.output_size - 1,), obs[0, 0, 1])]), state


def scripted_policy(duration_range=(2, 6)) -> HierarchicalPolicy:
    low = PMTGPolicy(17, latent=(0.0, 0.0))
    return HierarchicalPolicy(ScriptedHighLevel(), low, 17, duration_range=duration_range)


def test_the_latent_changes_exactly_where_the_counter_runs_out_under_vmap():
    """Four episodes in one ``vmap``, 12 control steps in a ``scan``. At step ``t`` episode
    ``e``'s high level offers the latent ``t + 1 + 100 e`` and a duration: 2 steps (episode 0),
    4 (episode 1), 6 (episode 2), and for episode 3, 6 steps when asked at step 2 but 2 steps at
    every other step. The command is taken at step 0 and then only where the previous one's
    steps are used up, so (worked out by hand):

    - 2 steps: taken at 0, 2, 4, 6, 8, 10;
    - 4 steps: taken at 0, 4, 8;
    - 6 steps: taken at 0, 6;
    - episode 3: taken at 0 (2 steps), 2 (6 steps: what it says at steps 3-7 is not read), 8
      (2 steps), 10.

    The low level acts on the held latent at every step (its action is PMTG's with that latent)."""
    policy = scripted_policy()
    episodes, steps = 4, 12
    t = np.arange(steps)[:, None]
    e = np.arange(episodes)[None, :]
    durations = np.broadcast_to(np.array([-1.0, 0.0, 1.0, -1.0]), (steps, episodes)).copy()
    durations[2, 3] = 1.0
    offered = (t + 1 + 100 * e).astype(np.float32)
    images = np.zeros((steps, episodes, 2, 2, 3), np.float32)
    images[..., 0, 0, 0], images[..., 0, 0, 1] = durations, offered
    state_obs = np.random.default_rng(0).normal(size=(steps, episodes, 17)).astype(np.float32)
    params = policy.init(jax.random.PRNGKey(0))
    key = jax.random.PRNGKey(1)
    params["low"]["w"] = 0.1 * jax.random.normal(key, params["low"]["w"].shape)  # the action depends on the latent

    @jax.jit
    def run(images, state_obs):
        first = jax.vmap(policy.initial_state)(jax.random.split(key, episodes))

        def step(state, inputs):
            pixels, obs_state = inputs
            action, state = jax.vmap(policy.apply, in_axes=(None, 0, 0))(
                params, {"pixels": pixels, "state": obs_state}, state
            )
            return state, (action, state.latent, state.counter, state.phase)

        return jax.lax.scan(step, first, (images, state_obs))[1]

    actions, latents, counters, phases = run(images, state_obs)
    taken_at = {0: [0, 2, 4, 6, 8, 10], 1: [0, 4, 8], 2: [0, 6], 3: [0, 2, 8, 10]}
    expected = np.array(
        [
            [1, 1, 3, 3, 5, 5, 7, 7, 9, 9, 11, 11],
            [101, 101, 101, 101, 105, 105, 105, 105, 109, 109, 109, 109],
            [201, 201, 201, 201, 201, 201, 207, 207, 207, 207, 207, 207],
            [301, 301, 303, 303, 303, 303, 303, 303, 309, 309, 311, 311],
        ],
        np.float32,
    ).T  # (steps, episodes)
    np.testing.assert_array_equal(latents[..., 0], expected)
    np.testing.assert_array_equal(latents[..., 1], expected)
    # the counter: the steps the command still holds after this one; 0 where it is asked anew
    for episode, starts in taken_at.items():
        changed = [s for s in range(1, steps) if latents[s, episode, 0] != latents[s - 1, episode, 0]]
        assert changed == starts[1:], episode
        asked_next = [s + 1 for s in range(steps - 1) if counters[s, episode] == 0]
        assert asked_next == starts[1:], episode
    np.testing.assert_array_equal(counters[:, 2], [5, 4, 3, 2, 1, 0, 5, 4, 3, 2, 1, 0])
    # the low level acted on the held latent, with its own phase
    previous_phase = np.concatenate([np.zeros((1, episodes), np.float32), np.asarray(phases[:-1])])
    for s in range(steps):
        for episode in range(episodes):
            action, low_state = policy.low.apply(
                params["low"],
                state_obs[s, episode],
                PMTGState(latent=jnp.asarray(expected[s, episode]).repeat(2), phase=previous_phase[s, episode]),
            )
            np.testing.assert_allclose(actions[s, episode], action, atol=1e-5)
            np.testing.assert_allclose(phases[s, episode], low_state.phase, atol=1e-6)


def test_duration_maps_linearly_onto_whole_control_steps():
    d = jnp.array([-1.0, -0.5, 0.0, 0.5, 1.0, -3.0, 2.0])
    np.testing.assert_array_equal(duration_steps(d, (10, 50)), [10, 20, 30, 40, 50, 10, 50])
    np.testing.assert_array_equal(duration_steps(jnp.array([-1.0, 0.0, 1.0]), (1, 1)), [1, 1, 1])
    assert duration_steps(jnp.array(0.0), (10, 50)).dtype == jnp.int32


def test_presets_high_levels_and_their_sizes():
    """Parameter counts worked out by hand. IAP (ReLU, 4x4 patches of the 24x32x3 image, d 4,
    top 10 -> linear to 1 + 4): W_Q and W_K 48 x 4 each, then 20 x 5 + 5. The CNN: 3x3
    convolutions 3->8, 8->16, 16->16 with biases; 24x32 -> 12x16 -> 6x8 -> 6x8, pooled 2x2 to
    3x4x16 = 192 -> 16 (tanh) -> 5. The low level: (4 + 17 + 2) x 16 + 16."""
    low = 23 * 16 + 16
    iap = 2 * 48 * 4 + 20 * 5 + 5
    cnn = (27 * 8 + 8) + (72 * 16 + 16) + (144 * 16 + 16) + (192 * 16 + 16) + (16 * 5 + 5)
    assert (low, iap, cnn) == (384, 489, 6885)
    from iap_mjx import configs

    counts = {}
    for name in ("iap", "cnn", "blind"):
        config = configs.get(f"quadruped-walls-{name}")
        policy = policies.make(config.policy.kind, OBS, 12, **dict(config.policy.options))
        params = policy.init(jax.random.PRNGKey(0))
        counts[name] = (policies.param_count(params), policy.level_param_counts(params))
    assert counts["iap"] == (iap + low, {"high": iap, "low": low})
    assert counts["blind"] == counts["iap"]
    assert counts["cnn"] == (cnn + low, {"high": cnn, "low": low})
    assert (cnn + low) / (iap + low) > 5 and cnn / iap > 10


def test_blind_high_level_sees_a_zeroed_image():
    """Two different images: the seeing policy's high level answers differently, the blind
    one's identically (and it exposes no patch selection: there is nothing it looks at)."""
    seeing = policies.make("hierarchical", OBS, 12, kernel="relu")
    blind = policies.make("hierarchical", OBS, 12, kernel="relu", blind=True)
    assert isinstance(seeing, AttentiveHierarchicalPolicy) and not hasattr(blind, "select")
    params = seeing.init(jax.random.PRNGKey(0))
    rng = np.random.default_rng(1)
    obs = [
        {"pixels": jnp.asarray(rng.uniform(size=OBS["pixels"]), jnp.float32), "state": jnp.zeros(17)} for _ in range(2)
    ]
    state = seeing.initial_state(jax.random.PRNGKey(0))
    latents = {
        name: [np.asarray(p.apply(params, o, state)[1].latent) for o in obs]
        for name, p in (("seeing", seeing), ("blind", blind))
    }
    assert not np.allclose(*latents["seeing"])
    np.testing.assert_array_equal(*latents["blind"])
    zero = {"pixels": jnp.zeros(OBS["pixels"]), "state": jnp.zeros(17)}
    np.testing.assert_array_equal(latents["blind"][0], seeing.apply(params, zero, state)[1].latent)
    selection = seeing.select(params, obs[0], state)
    assert selection.indices.shape == (10,) and seeing.layer.num_patches == 48


def test_convnet_output_is_clipped_not_squashed():
    net = ConvNet((24, 32, 3), 5)
    assert net.body.pooled_grid == (3, 4) and net.body.flat_size == 192
    params = net.init(jax.random.PRNGKey(0))
    last = params["dense"][-1]
    params["dense"][-1] = {"w": last["w"], "b": jnp.array([5.0, -5.0, 0.3, 0.0, 0.0])}
    out, _ = net.apply(params, jnp.zeros((24, 32, 3)), ())
    # on a black image the tanh layer gives tanh(b) = 0 (zero biases), so the output is the bias
    np.testing.assert_allclose(out, [1.0, -1.0, 0.3, 0.0, 0.0], atol=1e-6)
    with pytest.raises(ValueError, match="strides"):
        ConvNet((24, 32, 3), 5, strides=(2, 2))
    with pytest.raises(ValueError, match="shrinks to nothing"):
        ConvNet((4, 4, 3), 5, strides=(2, 2, 2))


def test_factory_names_bad_settings():
    with pytest.raises(ValueError, match="patch_size"):
        policies.make("hierarchical", OBS, 12, high_level="cnn", patch_size=2)
    with pytest.raises(ValueError, match="high_level"):
        policies.make("hierarchical", OBS, 12, high_level="mlp")
    with pytest.raises(ValueError, match="duration_range"):
        policies.make("hierarchical", OBS, 12, duration_range=(0, 10))
    with pytest.raises(ValueError, match="duration_range"):
        policies.make("hierarchical", OBS, 12, duration_range=(20, 10))
    with pytest.raises(ValueError, match="pixels\\+state"):
        policies.make("hierarchical", (24, 32, 3), 12)
    with pytest.raises(ValueError, match="low_level_init"):
        policies.make("hierarchical", OBS, 12, low_level_init="/nonexistent.npz")
    table2 = policies.make("hierarchical", OBS, 12, kernel="relu", patch_size=2, stride=1)
    assert table2.layer.num_patches == 23 * 31
    imu = policies.make("hierarchical", OBS, 12, high_level="cnn", high_level_imu=True)
    assert imu.high.state_size == 5


def test_low_level_from_a_file_with_its_normalisation_folded_in(tmp_path):
    """A low level trained on normalised observations, folded into raw-observation weights,
    gives the same outputs on raw observations (within 5 standard deviations, where the
    normaliser does not clip); the hierarchy starts from those weights."""
    rng = np.random.default_rng(2)
    low = PMTGPolicy(17)
    w = rng.normal(size=(low.input_size, low.output_size)).astype(np.float32) * 0.3
    b = rng.normal(size=low.output_size).astype(np.float32) * 0.3
    stats = ObsStats(
        count=jnp.array(100.0),
        mean=jnp.asarray(rng.normal(size=17), jnp.float32),
        var=jnp.asarray(rng.uniform(0.5, 2.0, 17), jnp.float32),
    )
    raw = stats.mean + jnp.sqrt(stats.var) * jnp.asarray(rng.uniform(-3, 3, 17), jnp.float32)
    state = PMTGState(latent=jnp.zeros(4), phase=jnp.array(1.0))
    trained = low.outputs({"w": jnp.asarray(w), "b": jnp.asarray(b)}, normalize(stats, raw), state)
    folded_w, folded_b = fold_normalisation(w, b, stats.mean, stats.var, latent_size=4)
    np.testing.assert_allclose(low.outputs({"w": folded_w, "b": folded_b}, raw, state), trained, atol=1e-5)
    path = tmp_path / "low.npz"
    np.savez(path, w=folded_w, b=folded_b)
    policy = policies.make("hierarchical", OBS, 12, high_level="cnn", low_level_init=str(path))
    params = policy.init(jax.random.PRNGKey(0))
    np.testing.assert_array_equal(params["low"]["w"], folded_w)
    np.savez(tmp_path / "bad.npz", w=folded_w[:5], b=folded_b)
    with pytest.raises(ValueError, match="low_level_init"):
        policies.make("hierarchical", OBS, 12, low_level_init=str(tmp_path / "bad.npz"))


def test_a_trained_policy_evaluates_with_its_eyes_closed():
    """The condition ``policy.blind=true`` (Figure 11's eyes-closed evaluation) gives a shipped
    seeing run's parameters to the blind hierarchy: two different images, one command; the
    same parameters with their eyes open answer the two differently."""
    from pathlib import Path

    from iap_mjx import es

    run = Path(__file__).resolve().parent.parent / "pretrained" / "quadruped" / "quadruped-walls-iap-seed0"
    seeing = es.load_run(run)
    closed = es.in_condition(seeing, ["policy.blind=true"])
    assert isinstance(seeing.policy, AttentiveHierarchicalPolicy) and seeing.policy.blind is False
    assert closed.policy.blind is True and dict(closed.config.policy.options)["blind"] is True
    assert closed.config.env == seeing.config.env and closed.config.es == seeing.config.es
    rng = np.random.default_rng(2)
    obs = [
        {"pixels": jnp.asarray(rng.uniform(size=OBS["pixels"]), jnp.float32), "state": jnp.zeros(17)} for _ in range(2)
    ]
    state = seeing.policy.initial_state(jax.random.PRNGKey(0))
    latents = {
        name: [np.asarray(result.policy.apply(seeing.params, o, state)[1].latent) for o in obs]
        for name, result in (("seeing", seeing), ("closed", closed))
    }
    assert not np.allclose(*latents["seeing"])
    np.testing.assert_array_equal(*latents["closed"])


def test_a_turn_trained_low_level_takes_its_command_from_the_latent():
    """``commanded_low_level``: the hierarchy's low level on latent ``(c, 0, 0, 0)`` and state
    ``s`` gives the action the quadruped-turn policy gives on observation ``[c, s]``."""
    rng = np.random.default_rng(3)
    turn = PMTGPolicy(18)  # observes [command, state (17)], latent (0, 0, 0, 0) as trained
    trained = {
        "w": jnp.asarray(rng.normal(0.0, 0.3, (turn.input_size, turn.output_size)), jnp.float32),
        "b": jnp.asarray(rng.normal(0.0, 0.3, turn.output_size), jnp.float32),
    }
    w, b = commanded_low_level(trained["w"], trained["b"], 4)
    low = PMTGPolicy(17)
    assert w.shape == (low.input_size, low.output_size) and not w[1:4].any()
    for command in (-0.7, 0.0, 1.0):
        state, phase = jnp.asarray(rng.normal(size=17), jnp.float32), jnp.float32(rng.uniform(0, 6))
        expected, _ = turn.apply(
            trained, jnp.concatenate([jnp.array([command]), state]), PMTGState(latent=jnp.zeros(4), phase=phase)
        )
        latent = jnp.array([command, 0.0, 0.0, 0.0], jnp.float32)
        action, _ = low.apply({"w": jnp.asarray(w), "b": jnp.asarray(b)}, state, PMTGState(latent=latent, phase=phase))
        np.testing.assert_allclose(action, expected, atol=1e-6)


def test_the_shipped_turn_run_is_the_shipped_low_level():
    """``low_level_weights`` end to end on the shipped ``quadruped-turn-pmtg`` run: its
    normalisation folded in and its command moved into the latent, the hierarchy's low level on
    raw state ``s`` and latent ``(c, 0, 0, 0)`` acts as the trained policy on the normalised
    ``[c, s]``; and ``pretrained/quadruped-turn/low-level-seed0.npz`` (Figure 11's
    ``fig11-turn`` low level) is exactly what it gives."""
    from pathlib import Path

    from iap_mjx import es
    from iap_mjx.policies.hierarchical import low_level_weights

    shipped = Path(__file__).resolve().parent.parent / "pretrained" / "quadruped-turn"
    turn = es.load_run(shipped / "quadruped-turn-pmtg-seed0")
    stats = turn.obs_stats
    w, b = low_level_weights(turn.policy, turn.params, stats, turn.config.env.name)
    with np.load(shipped / "low-level-seed0.npz") as stored:
        np.testing.assert_array_equal(stored["w"], w)
        np.testing.assert_array_equal(stored["b"], b)
    low = PMTGPolicy(17)
    rng = np.random.default_rng(4)
    for phase in (0.5, 2.0, 4.0):
        raw = stats.mean + jnp.sqrt(stats.var) * jnp.asarray(rng.uniform(-3, 3, 18), jnp.float32)
        state = PMTGState(latent=jnp.zeros(4), phase=jnp.float32(phase))
        trained = turn.policy.outputs(turn.params, normalize(stats, raw), state)
        latent = jnp.zeros(4).at[0].set(raw[0])
        folded = low.outputs({"w": jnp.asarray(w), "b": jnp.asarray(b)}, raw[1:], state.replace(latent=latent))
        np.testing.assert_allclose(folded, trained, rtol=1e-4, atol=1e-4)
