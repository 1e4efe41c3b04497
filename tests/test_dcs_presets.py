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
import spread
from dm_control import suite

from iap_mjx import configs, envs, policies
from iap_mjx.envs import distraction

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


DISTRACTION_SETTINGS = ("distraction", "dynamic", "distraction_kinds", "background_dir", "background_size",
                        "background_frames")
"""The env settings of the distraction: the rest of a preset's settings make its undistracted env."""
STEPS = 5
"""Env steps of the stepped comparisons (40 control steps at action repeat 8; episodes are 10)."""
PHYSICS_ATOL = 2e-5
"""Distracted against dm_control: the state observation after each env step, where dm_control's
own float32-noise spread is <= 1e-5 (no contacts): measured gap 1.8e-6; a wrong physics step
(two per control step) is 0.27 off after the first env step."""
REWARD_ATOL = 1e-5
"""The same for one env step's reward, a sum of 8 control steps' rewards: measured gap 5.4e-7."""
SAME_KEY_ATOL = 1e-6
"""Distracted against undistracted from the same key, every float of the physics state: the
same float32 computation twice (measured gap 0, bit for bit). Cartpole's reset draws its
coordinates as 1e-2 x N(0, 1) from the key (the 6 keys here span 0.016 and 0.033), so a key
that the distraction consumed or changed moves the reset state by that much: the chance that a
different key lands within 1e-6 in each of the 4 drawn coordinates is below 1e-16 per episode."""


def test_quick_preset_episode_is_distracted_deterministic_and_leaves_physics_alone():
    """dcs-cartpole-swingup-quick (action repeat 8) at 60x80, made dynamic so that walks can
    be counted; 12 distracted episodes in one program, each with its own key: 6 from one
    dm_control state (``reset_to``) under one action sequence, 6 drawn from their keys
    (``reset``), each under its own actions; then an ended step and an ended step showing
    another episode's perturbation.

    The physics is checked against two references over ``STEPS`` env steps:

    - dm_control itself: each of the first six (all perturbed differently) follows dm_control's
      own trajectory from that state under the same actions, state observation and reward
      after every env step, within ``PHYSICS_ATOL``/``REWARD_ATOL`` plus 100 x dm_control's
      spread under float32 noise (``tests/spread.py``); dm_control with a wrong physics step
      must break that bound;
    - the undistracted env from the same keys (the last six): the same preset without its
      distraction settings (state observations: no camera), reset from the same keys and
      stepped with the same actions; every float of ``State.data``, the reward and ``done``
      agree within ``SAME_KEY_ATOL`` at reset and after each step.
    """
    config = configs.get("dcs-cartpole-swingup-quick")
    overrides = {**dict(config.env.overrides), "height": 60, "width": 80, "dynamic": True}
    env = envs.make(config.env.name, **overrides)
    plain = envs.make(config.env.name, **{**{k: v for k, v in overrides.items() if k not in DISTRACTION_SETTINGS},
                                          "obs_mode": "state"})
    assert plain.config.action_repeat == env.config.action_repeat == SUITE[config.env.name]
    reference = suite.load("cartpole", "swingup", task_kwargs={"random": 0})
    reference.reset()
    start = reference.physics.data
    keys = jax.random.split(jax.random.PRNGKey(4), 12)
    shuffle = jnp.roll(jnp.arange(12), -1)
    rng = np.random.default_rng(0)
    common = rng.uniform(-1, 1, (STEPS, 1, env.action_size))
    own = rng.uniform(-1, 1, (STEPS, 6, env.action_size))
    actions = np.concatenate([np.broadcast_to(common, (STEPS, 6, env.action_size)), own], axis=1)
    phases = jnp.asarray([0] * STEPS + [1, 2])

    @jax.jit
    def run(keys, actions):
        from_state = jax.vmap(lambda k: env.reset_to(start.qpos, start.qvel, key=k))(keys[:6])
        drawn = jax.vmap(env.reset)(keys[6:])
        first = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), from_state, drawn)
        padded = jnp.concatenate([actions, jnp.full((2, 12, env.action_size), 0.5)])

        def step(s, inputs):
            # phase 1: the episode has ended; phase 2: ended, with another episode's perturbation
            phase, action = inputs
            other = s.replace(info={**s.info, "distraction": jax.tree.map(lambda x: x[shuffle],
                                                                          s.info["distraction"])})
            s = jax.tree.map(lambda a, b: jnp.where(phase == 2, b, a), s, other)
            s = s.replace(done=jnp.where(phase > 0, jnp.ones_like(s.done), s.done))
            s = jax.vmap(env.step)(s, action)
            return s, (s, jax.vmap(env.state_observation)(s.data))

        states, observations = jax.lax.scan(step, first, (phases, padded))[1]
        plain_first = jax.vmap(plain.reset)(keys[6:])
        plain_states = jax.lax.scan(lambda s, a: (jax.vmap(plain.step)(s, a),) * 2, plain_first,
                                    actions[:, 6:])[1]
        two = jax.vmap(lambda p: env.distraction.advance(p, 8))(first.info["distraction"])
        seen = jax.vmap(lambda d, p: env.distraction.scene(d, p)[0].cam_xpos[0])(
            first.data, first.info["distraction"])
        return first, states, observations, plain_first, plain_states, two, seen

    first, states, observations, plain_first, plain_states, walked, seen = run(keys, actions)
    again = run(keys, actions)[0]
    moved, last, ended, swapped = (jax.tree.map(lambda x, i=i: x[i], states) for i in (0, STEPS - 1, STEPS, STEPS + 1))
    p0, p1 = first.info["distraction"], moved.info["distraction"]
    # determinism: the same program on the same keys gives the same draw; episodes differ
    for a, b in zip(jax.tree.leaves(p0), jax.tree.leaves(again.info["distraction"])):
        np.testing.assert_array_equal(a, b)
    sphere, colour = np.asarray(p0.camera.sphere), np.asarray(p0.colour).reshape(12, -1)
    for i in range(12):
        for j in range(i):
            assert not np.allclose(sphere[i], sphere[j]) and not np.allclose(colour[i], colour[j])
    # the reset state is dm_control's (its qpos, its unperturbed camera); the perturbed pose
    # exists only in what is rendered
    np.testing.assert_allclose(first.data.qpos[:6], np.broadcast_to(start.qpos, (6, len(start.qpos))), atol=1e-6)
    np.testing.assert_allclose(first.data.cam_xpos[:6, 0], np.broadcast_to(start.cam_xpos[0], (6, 3)), atol=1e-4)
    assert np.all(np.linalg.norm(np.asarray(seen) - np.asarray(first.data.cam_xpos[:, 0]), axis=-1) > 1e-3)

    # physics against dm_control: the six episodes from its state, after each env step
    repeat = env.config.action_repeat
    control_actions = np.repeat(common[:, 0], repeat, axis=0)
    theirs_obs, theirs_reward = spread.dm_control_run(config.env.name, 0, control_actions)
    per_step = slice(repeat - 1, None, repeat)

    def per_env_step(obs, reward):
        return obs[per_step], reward.reshape(STEPS, repeat).sum(1)

    reference_obs, reference_reward = per_env_step(theirs_obs, theirs_reward)
    runs = [per_env_step(*spread.dm_control_run(config.env.name, 0, control_actions, rng=noise))
            for noise in spread.noise_generators()]
    obs_spread = spread.spread(reference_obs, [obs for obs, _ in runs])
    reward_spread = spread.spread(reference_reward, [reward for _, reward in runs])
    ours_obs = np.asarray(observations[:STEPS, :6])
    ours_reward = np.asarray(states.reward[:STEPS, :6])
    for e in range(6):
        spread.assert_within_spread(ours_obs[:, e], reference_obs, obs_spread, atol=PHYSICS_ATOL,
                                    what=f"distracted episode {e}: state observation")
        spread.assert_within_spread(ours_reward[:, e], reference_reward, reward_spread, atol=REWARD_ATOL,
                                    what=f"distracted episode {e}: reward")
    wrong_obs, _ = spread.dm_control_run(config.env.name, 0, control_actions,
                                         sub_steps=spread.wrong_sub_steps(plain.n_sub_steps))
    spread.assert_wrong_step_is_caught(wrong_obs[per_step], reference_obs, obs_spread, atol=PHYSICS_ATOL)

    # physics against the undistracted env from the same keys, at reset and after each step
    def physics(state, batch):
        return {"data": [x[batch] for x in jax.tree.leaves(state.data)],
                "reward": state.reward[batch], "done": state.done[batch]}

    for when, ours, theirs in [("reset", physics(first, np.s_[6:]), physics(plain_first, np.s_[:])),
                               ("steps", physics(states, np.s_[:STEPS, 6:]), physics(plain_states, np.s_[:]))]:
        for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(theirs)):
            np.testing.assert_allclose(a, b, rtol=0, atol=SAME_KEY_ATOL, err_msg=when)
    assert np.ptp(np.asarray(first.data.qpos[6:]), axis=0).min() > 1e-3  # the keys drew different states

    # one env step = 8 control steps of every walk
    np.testing.assert_allclose(p1.camera.sphere, walked.camera.sphere, atol=1e-5)
    np.testing.assert_allclose(p1.colour, walked.colour, atol=1e-6)
    np.testing.assert_array_equal(p1.frame, walked.frame)
    assert not np.allclose(p1.camera.sphere, p0.camera.sphere)
    # ended: physics and perturbation hold, so the frame is the same picture: the step draws
    # the state's own (advanced) perturbation; another episode's perturbation changes it
    for a, b in zip(jax.tree.leaves(ended.info["distraction"]), jax.tree.leaves(last.info["distraction"])):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(ended.obs, last.obs, atol=1e-6)
    for i in range(12):
        assert np.abs(np.asarray(swapped.obs[i]) - np.asarray(last.obs[i])).mean() > 0.02, i
