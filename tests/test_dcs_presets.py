"""The ``dcs-<task>`` presets: the paper's Table-1 setting on each of the suite's six tasks,
validated without building anything (the quick preset's policy fits its frames); and one
quick preset's env in one compiled program: distracted frames, the perturbation drawn from the
episode's key (the same key, the same draw; episodes differ), advanced once per control step
(action repeat k: k walks per env step), held once the episode has ended, shown in the
frames, and never touching the physics."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from iap_mjx import configs, envs, policies
from iap_mjx.envs import distraction
from iap_mjx.viz import render_compare

SUITE = {"cartpole-swingup": 8, "cheetah-run": 4, "ball_in_cup-catch": 4, "reacher-easy": 4,
         "walker-walk": 2, "finger-spin": 2}
"""The suite's six tasks and their action repeats (PlaNet/DrQ's, as the issue states them)."""


def test_every_suite_task_has_a_preset():
    assert sorted(distraction.TASKS) == sorted(SUITE)
    names = [name for name in configs.names() if name.startswith("dcs-")]
    assert sorted(names) == sorted([f"dcs-{t}" for t in SUITE] + [f"dcs-{t}-quick" for t in SUITE])


@pytest.mark.parametrize("task", sorted(SUITE))
def test_preset_is_the_papers_setting(task):
    config = configs.get(f"dcs-{task}")
    env_config = envs.check(config.env.name, **dict(config.env.overrides))
    assert config.env.name == task
    assert (env_config.height, env_config.width, env_config.obs_mode) == (240, 320, "pixels")
    assert env_config.action_repeat == SUITE[task]
    dcs = env_config.distraction_config()
    assert (dcs.difficulty, dcs.dynamic, dcs.kinds) == ("medium", False, ("background", "camera", "colour"))
    options = dict(config.policy.options)
    assert config.policy.kind == "iap"
    assert (options["patch_size"], options["top_l"], options["kernel"], options["m"], options["r"],
            options["controller"]) == (2, 10, "hybrid", 10, 5, "lstm")
    quick = configs.get(f"dcs-{task}-quick")
    assert quick.policy == config.policy and quick.env.name == config.env.name
    assert envs.check(quick.env.name, **dict(quick.env.overrides)).distraction_config().kinds == dcs.kinds
    # the policy attends over the native frame's 2x2 patches: L = 19,200, as the paper
    policy = policies.make(config.policy.kind, (240, 320, 3), 1, **options)
    assert policy.layer.num_patches == 19200


def test_quick_preset_episode_is_distracted_deterministic_and_leaves_physics_alone():
    """dcs-cartpole-swingup-quick (action repeat 8) at 60x80, made dynamic so that walks can
    be counted; 6 episodes from one dm_control state, each with its own key."""
    config = configs.get("dcs-cartpole-swingup-quick")
    overrides = {**dict(config.env.overrides), "height": 60, "width": 80, "dynamic": True}
    env = envs.make(config.env.name, **overrides)
    (model, state), = render_compare.suite_states("cartpole", "swingup", n_states=1, seed=0)
    keys = jax.random.split(jax.random.PRNGKey(4), 6)
    shuffle = jnp.array([1, 2, 3, 4, 5, 0])

    @jax.jit
    def run(keys):
        first = jax.vmap(lambda k: env.reset_to(state.qpos, state.qvel, key=k))(keys)

        def step(s, phase):
            # phase 1: the episode has ended; phase 2: ended, with another episode's perturbation
            other = s.replace(info={**s.info, "distraction": jax.tree.map(lambda x: x[shuffle],
                                                                          s.info["distraction"])})
            s = jax.tree.map(lambda a, b: jnp.where(phase == 2, b, a), s, other)
            s = s.replace(done=jnp.where(phase > 0, jnp.ones_like(s.done), s.done))
            s = jax.vmap(env.step)(s, jnp.full((6, env.action_size), 0.5))
            return s, s

        states = jax.lax.scan(step, first, jnp.arange(3))[1]
        two = jax.vmap(lambda p: env.distraction.advance(p, 8))(first.info["distraction"])
        seen = jax.vmap(lambda d, p: env.distraction.scene(d, p)[0].cam_xpos[0])(
            first.data, first.info["distraction"])
        return first, states, two, seen

    first, states, walked, seen = run(keys)
    again = run(keys)[0]
    moved, ended, swapped = (jax.tree.map(lambda x, i=i: x[i], states) for i in range(3))
    p0, p1 = first.info["distraction"], moved.info["distraction"]
    # determinism: the same program on the same keys gives the same draw; episodes differ
    for a, b in zip(jax.tree.leaves(p0), jax.tree.leaves(again.info["distraction"])):
        np.testing.assert_array_equal(a, b)
    sphere, colour = np.asarray(p0.camera.sphere), np.asarray(p0.colour).reshape(6, -1)
    for i in range(6):
        for j in range(i):
            assert not np.allclose(sphere[i], sphere[j]) and not np.allclose(colour[i], colour[j])
    # physics untouched: the state is dm_control's (its qpos, its unperturbed camera); the
    # perturbed pose exists only in what is rendered
    np.testing.assert_allclose(first.data.qpos, np.broadcast_to(state.qpos, (6, model.nq)), atol=1e-6)
    np.testing.assert_allclose(first.data.cam_xpos[:, 0], np.broadcast_to(state.cam_xpos[0], (6, 3)), atol=1e-4)
    assert np.all(np.linalg.norm(np.asarray(seen) - np.asarray(first.data.cam_xpos[:, 0]), axis=-1) > 1e-3)
    # one env step = 8 control steps of every walk
    np.testing.assert_allclose(p1.camera.sphere, walked.camera.sphere, atol=1e-5)
    np.testing.assert_allclose(p1.colour, walked.colour, atol=1e-6)
    np.testing.assert_array_equal(p1.frame, walked.frame)
    assert not np.allclose(p1.camera.sphere, p0.camera.sphere)
    # ended: physics and perturbation hold, so the frame is the same picture: the step draws
    # the state's own (advanced) perturbation; another episode's perturbation changes it
    for a, b in zip(jax.tree.leaves(ended.info["distraction"]), jax.tree.leaves(p1)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(ended.obs, moved.obs, atol=1e-6)
    for i in range(6):
        assert np.abs(np.asarray(swapped.obs[i]) - np.asarray(moved.obs[i])).mean() > 0.02, i
