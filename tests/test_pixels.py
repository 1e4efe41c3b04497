"""Pixel observations: shapes, frame stacking, RGB-D and pixels+state, and the frames agree
with MuJoCo's ``mj_ray`` on an env's own state (reacher: the camera must follow the target,
which the env keeps in ``State.info`` rather than in the model)."""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from iap_mjx import envs
from iap_mjx.envs.pixels import with_pixels

SIZE = 32


@pytest.fixture(scope="module")
def cartpole():
    return envs.make("cartpole-swingup", obs_mode="pixels_depth", height=SIZE, width=SIZE, frame_stack=3)


def test_make_wires_pixel_modes():
    for mode, channels in (("pixels", 3), ("pixels_depth", 4)):
        env = envs.make("cartpole-swingup", obs_mode=mode, height=SIZE, width=SIZE + 8, frame_stack=2)
        assert env.observation_shape == (SIZE, SIZE + 8, 2 * channels)
    env = envs.make("cartpole-swingup", obs_mode="pixels+state", height=SIZE, width=SIZE)
    assert env.observation_shape == {"pixels": (SIZE, SIZE, 3), "state": env.env.observation_shape}
    with pytest.raises(ValueError, match="obs_mode"):
        with_pixels(env.env, obs_mode="rgb")
    with pytest.raises(ValueError, match="frame_stack"):
        with_pixels(env.env, frame_stack=0)


def test_frame_stack_and_depth_under_vmap(cartpole):
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    reset = jax.jit(jax.vmap(cartpole.reset))
    step = jax.jit(jax.vmap(cartpole.step))
    state = reset(keys)
    assert state.obs.shape == (2, SIZE, SIZE, 12) and state.obs.dtype == jnp.float32
    first = np.asarray(state.obs)
    for i in range(3):  # the reset frame fills the whole stack
        np.testing.assert_array_equal(first[..., 4 * i : 4 * i + 4], first[..., :4])
    actions = jnp.ones((2, cartpole.action_size))
    states = [state]
    for _ in range(3):
        states.append(step(states[-1], actions))
    obs = np.asarray(states[-1].obs)
    for back in range(3):  # oldest first: channels [4i, 4i+4) are the frame of step 1 + i
        frame = jax.vmap(cartpole.render)(states[1 + back].data)
        # float rounding only: the frame rendered op by op here and fused inside the jitted step
        # differ by up to ~1e-5 on a few pixels (XLA:CPU's loop emitters, as the tests compile)
        np.testing.assert_allclose(obs[..., 4 * back : 4 * back + 4], np.asarray(frame), atol=1e-4)
    rgb = obs[..., -4:-1]
    assert 0.0 <= rgb.min() and rgb.max() <= 1.0
    depth, _ = jax.vmap(cartpole.camera.trace)(states[-1].data)
    np.testing.assert_allclose(obs[..., -1], np.asarray(depth), rtol=1e-6)
    assert not np.allclose(obs[..., -4:], obs[..., 4:8]), "the cart should move in 3 steps"


def test_pixels_plus_state_keeps_the_state_observation():
    env = envs.make("reacher-easy", obs_mode="pixels+state", height=SIZE, width=SIZE)
    state = jax.jit(env.reset)(jax.random.PRNGKey(1))
    np.testing.assert_allclose(state.obs["state"], env.state_observation(state.data), rtol=1e-6)
    assert state.obs["pixels"].shape == (SIZE, SIZE, 3)


def test_env_frames_match_mj_ray():
    """The env's rendered geometry equals MuJoCo's ray caster on the same state."""
    env = envs.make("reacher-easy", obs_mode="pixels", height=SIZE, width=SIZE)
    state = jax.jit(env.reset)(jax.random.PRNGKey(2))
    depth, ids = (np.asarray(a) for a in jax.jit(env.camera.trace)(state.data))
    model = copy.copy(env.mj_model)
    data = mujoco.MjData(model)
    data.qpos[:] = np.asarray(state.data.qpos)
    target = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "target")
    model.geom_pos[target, :2] = np.asarray(state.info["target"])  # dm_control's way
    mujoco.mj_forward(model, data)
    cam = env.camera
    rot = data.cam_xmat[cam.config.camera_id].reshape(3, 3)
    dirs = cam.ray_directions().reshape(-1, 3).astype(np.float64) @ rot.T
    hit_id = np.zeros(1, np.int32)
    agree = []
    for direction, our_depth, our_id in zip(dirs, depth.reshape(-1), ids.reshape(-1)):
        dist = mujoco.mj_ray(
            model,
            data,
            data.cam_xpos[cam.config.camera_id],
            direction,
            np.array([1, 1, 1, 0, 0, 0], np.uint8),
            1,
            -1,
            hit_id,
        )
        ref_id = hit_id[0] if 0 <= dist < cam.zfar else -1
        ok = our_id == ref_id and (ref_id < 0 or abs(our_depth - dist) <= 1e-4 * dist)
        agree.append(ok)
    assert np.mean(agree) >= 0.995
    assert (ids == target).any(), "the target should be in view"
