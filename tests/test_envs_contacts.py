"""The contact-slot limit (``EnvConfig.max_contacts``): same physics while it is not full,
and a reported saturation when it is."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mujoco import mjx

from iap_mjx import envs

STEPS = 60


def _run(env):
    """Two cheetahs dropped from 0.1 m and 0.2 m above their standing pose (``reset_to``: a
    program without ``reset``'s 200 settling steps), ``STEPS`` steps of saturated alternating
    actions: feet, shins and thighs hit the floor. Returns the last states and, per cheetah and
    step, the state before it (``qpos``, ``qvel``), its action and the touching contacts after."""
    qpos = jnp.zeros((2, env.mj_model.nq)).at[:, 1].set(jnp.array([0.1, 0.2]))
    signs = jnp.sign(jnp.sin(jnp.arange(STEPS)[:, None] / 5.0 + jnp.arange(6)[None, :]))
    actions = jnp.broadcast_to(signs, (2, STEPS, 6)).astype(jnp.float32)

    def episode(qpos, actions):
        def step(state, action):
            after = env.step(state, action)
            touching = jnp.sum(after.data._impl.contact.dist < 0)
            return after, (state.data.qpos, state.data.qvel, action, touching)

        return jax.lax.scan(step, env.reset_to(qpos, jnp.zeros(env.mj_model.nv)), actions)

    return jax.jit(jax.vmap(episode))(qpos, actions)


def _one_step_gaps(candidates, reference, qpos, qvel, actions):
    """Per env of ``candidates`` and per state: the largest ``|qpos|`` difference after one
    step of the env and of ``reference`` from the same ``qpos``, ``qvel`` and action (leading
    axes flattened), and whether the env's contact slots saturated on that step: a list of
    ``(gaps (N,), saturated (N,))``, one per candidate. One program: the reference's step is
    traced once for every candidate."""

    def gaps(q, v, a):
        theirs = reference.step(reference.reset_to(q, v), a)
        ours = [env.step(env.reset_to(q, v), a) for env in candidates]
        return [(jnp.max(jnp.abs(o.data.qpos - theirs.data.qpos)), o.metrics["contact_saturated"]) for o in ours]

    flat = lambda x: x.reshape(-1, x.shape[-1])  # noqa: E731
    return [tuple(map(np.asarray, pair)) for pair in jax.jit(jax.vmap(gaps))(flat(qpos), flat(qvel), flat(actions))]


class _Dropped:
    """The env, but ``reset(key)`` drops the cheetah from 0.1-0.2 m above its standing pose
    (``reset_to``: the ES rollout's program without ``reset``'s 200 settling steps)."""

    def __init__(self, env):
        self.env = env

    def __getattr__(self, name):
        return getattr(self.env, name)

    def reset(self, key):
        height = jax.random.uniform(key, (), minval=0.1, maxval=0.2)
        model = self.env.mj_model
        return self.env.reset_to(jnp.zeros(model.nq).at[1].set(height), jnp.zeros(model.nv))


def test_limit_shrinks_the_constraint_rows():
    limited, everything = envs.make("cheetah-run"), envs.make("cheetah-run", max_contacts="all")
    assert limited.max_contacts == 10 and everything.max_contacts is None
    rows = lambda env: mjx.make_data(env.mj_model)._impl.efc_J.shape[0]  # noqa: E731
    assert rows(limited) < rows(everything)


@pytest.mark.slow
def test_unsaturated_limit_keeps_the_physics_step():
    """From every state of the dropped cheetahs' run, a step with the task's contact limit
    equals a step with every contact kept, up to float32 rounding (the dropped candidates never
    touch; the solver has fewer rows, so it rounds differently). Compared step by step from the
    same state, not along two trajectories that contacts make diverge. With 2 slots, which
    saturate, some step differs by far more: the comparison sees a limit that drops a contact."""
    limited, everything = envs.make("cheetah-run"), envs.make("cheetah-run", max_contacts="all")
    final, (qpos, qvel, actions, touching) = _run(limited)
    assert np.asarray(touching).max(axis=1).min() >= 2  # both cheetahs hit the floor
    assert np.all(np.asarray(final.metrics["contact_saturated"]) == 0)
    # qpos is O(1): a few units in the last place of the solver's result, with room for
    # another CPU's rounding
    bound = 64 * np.finfo(np.float32).eps
    two = envs.make("cheetah-run", max_contacts=2)
    (gaps, saturated), (two_slots, two_saturated) = _one_step_gaps([limited, two], everything, qpos, qvel, actions)
    assert not saturated.any()
    assert gaps.max() <= bound, gaps.max()
    assert two_saturated.any() and two_slots.max() > 100 * bound, two_slots.max()


@pytest.mark.slow
def test_the_es_rollout_counts_saturated_episodes():
    """A too small limit is reported, and ``run_episode`` carries the env's flag into
    ``EpisodeResult.saturated``, which the training loop sums into
    ``contact_saturated_episodes``."""
    from iap_mjx.es.episode import run_episode
    from iap_mjx.policies import LinearPolicy

    policy = LinearPolicy(17, 6)
    params = jax.tree_util.tree_map(lambda x: x + 0.5, policy.init(None))  # a moving cheetah

    def saturated(max_contacts):
        env = _Dropped(envs.make("cheetah-run", max_contacts=max_contacts, episode_length=STEPS))
        one = lambda key: run_episode(env, policy, params, key, None, False).saturated  # noqa: E731
        return np.asarray(jax.jit(jax.vmap(one))(jax.random.split(jax.random.key(0), 2)))

    np.testing.assert_array_equal(saturated(1), [1.0, 1.0])
    np.testing.assert_array_equal(saturated("task"), [0.0, 0.0])


def _dm_control_max_touching(domain: str, task: str, steps: int = 1000) -> int:
    """Most contacts touching at once in dm_control over three 1000-step episodes of
    uniform, saturated and periodic actions."""
    from dm_control import suite

    env = suite.load(domain, task, task_kwargs={"random": 0})
    spec = env.action_spec()
    rng = np.random.default_rng(0)
    most = 0
    for mode in range(3):
        env.reset()
        for t in range(steps):
            if mode == 0:
                action = rng.uniform(spec.minimum, spec.maximum)
            elif mode == 1:
                action = np.where(rng.random(spec.shape) < 0.5, spec.minimum, spec.maximum)
            else:
                action = np.sign(np.sin(t / 7.0 + np.arange(spec.shape[0]))) * spec.maximum
            env.step(action)
            most = max(most, int(env.physics.data.ncon))
    return most


def test_task_defaults_leave_headroom_over_dm_control():
    """Each task's default slots are at least twice what dm_control ever has touching."""
    from mujoco.mjx._src import collision_driver

    for name in ("cheetah-run", "walker-walk", "ball_in_cup-catch", "finger-spin"):
        env = envs.make(name)
        domain, task = name.split("-")
        # None: no limit, every candidate slot (finger-spin has 4).
        slots = env.max_contacts or len(collision_driver.make_condim(env.mj_model))
        assert slots >= 2 * _dm_control_max_touching(domain, task), name
