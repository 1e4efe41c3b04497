"""``viz.attended``: which pixels a selected patch covers (the same ones the attention layer
cuts), counting the geoms they show, and a whole run over a distracted env's episodes."""

from __future__ import annotations

import types

import jax
import numpy as np
import pytest

from iap_mjx import cli, envs, policies
from iap_mjx.attention.patches import extract_patches, patch_grid
from iap_mjx.viz import attended, recording


def _layer(height, width, patch, stride):
    config = types.SimpleNamespace(patch_size=patch, effective_stride=stride)
    return types.SimpleNamespace(config=config, grid=patch_grid(height, width, patch, stride))


@pytest.mark.parametrize("patch, stride", [(2, 2), (3, 3), (4, 2)])
def test_patch_pixels_are_the_pixels_the_layer_cuts(patch, stride):
    height, width = 12, 18
    image = np.random.default_rng(0).random((height, width, 3), np.float32)
    layer = _layer(height, width, patch, stride)
    cut = np.asarray(extract_patches(image, patch, stride)[0])
    indices = np.arange(cut.shape[0])
    rows, columns = attended.patch_pixels(layer, indices)
    assert rows.shape == (cut.shape[0], patch * patch)
    np.testing.assert_array_equal(image[rows, columns].reshape(cut.shape), cut)


def test_count_geoms_counts_every_selected_pixel_per_step():
    geoms = np.full((2, 4, 4), -1)
    geoms[0, :2, :2] = [[5, 5], [5, 7]]  # patch 0 at step 0
    geoms[0, 2:, 2:] = 7  # patch 3 at step 0
    geoms[1, :2, 2:] = [[7, -1], [-1, -1]]  # patch 1 at step 1
    geoms[1, :2, :2] = 9  # patch 0 at step 1: not selected then
    counts = attended.count_geoms(geoms, np.array([[0, 3], [1, 1]]), _layer(4, 4, 2, 2))
    assert counts == {5: 3, 7: 1 + 4 + 2, -1: 6}


@pytest.mark.slow
def test_shares_over_a_distracted_episode_describe_the_frames_the_policy_saw():
    env = envs.make(
        "cartpole-swingup",
        obs_mode="pixels",
        height=48,
        width=64,
        action_repeat=8,
        distraction="medium",
        dynamic=False,
        episode_length=6,
        background_size=64,
        background_frames=4,
    )
    policy = policies.make("iap", env.observation_shape, env.action_size, patch_size=2, top_l=10)
    params = policy.init(jax.random.PRNGKey(1))
    program = attended.geom_episode_program(env, policy, steps=6)
    shares = attended.shares(attended.episode_counts(env, policy, params, episodes=1, seed=3, program=program))
    assert abs(sum(shares.values()) - 1.0) < 1e-9 and list(shares.values()) == sorted(shares.values(), reverse=True)
    names = {attended.geom_label(env.mj_model, g) for g in range(env.mj_model.ngeom)} | {attended.BACKGROUND}
    assert set(shares) <= names

    # the recorded geom maps are those of the frames the policy saw
    key = jax.random.split(jax.random.PRNGKey(3), 1)[0]
    record = recording.record_episode(env, policy, params, key, steps=6, program=program)
    first = jax.jit(env.reset)(jax.random.split(key)[0])
    direct = np.asarray(jax.jit(env.geom_map)(first.data, first.info["distraction"]))
    assert np.mean(record["geoms"][0] == direct) > 0.99
    assert (direct == -1).mean() > 0.2 and (direct >= 0).mean() > 0.2  # background and bodies both in view
    # the shares are this episode's selected pixels, counted again from its record
    counts = attended.count_geoms(record["geoms"], record["indices"], policy.layer)
    assert sum(counts.values()) == 6 * 10 * 4
    expected = {}
    for geom, count in counts.items():
        label = attended.geom_label(env.mj_model, geom)
        expected[label] = expected.get(label, 0.0) + count / (6 * 10 * 4)
    assert shares == pytest.approx(expected, abs=1e-12)


def test_the_checks_see_pixel_envs_and_attention_policies():
    """``PixelEnv`` forwards ``mj_model`` with ``__getattr__``: ``maps_geoms`` sees it (an
    ``isinstance`` on a runtime-checkable protocol does not, from Python 3.12)."""
    from iap_mjx.envs.pixels import maps_geoms
    from iap_mjx.policies.base import attends

    pixels, state = envs.make("cartpole-swingup", obs_mode="pixels", height=24, width=32), envs.make("cartpole-swingup")
    assert maps_geoms(pixels) and not maps_geoms(state)
    shape, actions = pixels.observation_shape, pixels.action_size
    assert attends(policies.make("iap", shape, actions, patch_size=4, top_l=4))
    assert not attends(policies.make("convnet", shape, actions, strides=(2, 2, 1))) and not attends(
        policies.make("linear", (5,), actions)
    )


def test_attended_refuses_a_state_policy():
    env = envs.make("cartpole-swingup")
    policy = policies.make("linear", env.observation_shape, env.action_size)
    with pytest.raises(ValueError, match="attention policy on a pixel env"):
        attended.episode_counts(env, policy, policy.init(jax.random.PRNGKey(0)))


def test_cli_attended_names_a_missing_run(tmp_path, capsys):
    assert cli.main(["attended", str(tmp_path / "nothing")]) == 2
    assert "error" in capsys.readouterr().err


def test_shares_and_table_over_episodes():
    counts = [{"cart": 30, "background": 10}, {"background": 50, "cart": 10}, {"pole": 20}]
    assert attended.shares(counts) == {"background": 60 / 120, "cart": 40 / 120, "pole": 20 / 120}
    table = attended.markdown(counts).splitlines()
    assert table[2] == "| background | 50.0% | 1 of 3 |"
    assert table[3] == "| cart | 33.3% | 1 of 3 |" and table[4] == "| pole | 16.7% | 1 of 3 |"


def test_shares_count_only_the_steps_taken_while_the_episode_lived():
    import mujoco

    model = mujoco.MjModel.from_xml_string("<mujoco><worldbody><geom name='robot' size='1'/></worldbody></mujoco>")
    env = types.SimpleNamespace(obs_mode="pixels", mj_model=model, geom_map=None)  # the program stands in for both
    policy = types.SimpleNamespace(select=None, layer=_layer(4, 4, 2, 2))
    geoms = np.zeros((3, 4, 4), np.int32)  # the robot fills steps 0 and 2, the background step 1
    geoms[1] = -1

    def program(params, obs_stats, key):  # an episode that ends at step 1 (a fall): step 2 is after it
        return {"geoms": geoms, "indices": np.zeros((3, 1), np.int32), "alive": np.array([1.0, 1.0, 0.0])}

    counts = attended.episode_counts(env, policy, None, episodes=1, steps=3, program=program)
    assert counts == [{"robot": 4, "background": 4}]  # step 2's 4 robot pixels are not counted
