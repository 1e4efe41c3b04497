"""One episode of an env driven by a policy: the step every episode takes and the one loop over it.

Training and evaluation (:mod:`iap_mjx.es.rollout` batches :func:`run_episode` over a
population), videos and attention shares (:mod:`iap_mjx.viz`) all run :func:`run_episode`.
Each step normalises the observation, asks the policy for an action and steps the env
(:func:`episode_step`), then adds the step to the episode's :class:`Tally`, which masks
everything after ``done`` or a non-finite reward/observation. What a caller keeps from each
step beyond the tally (a video's frames) its ``record`` hook returns; the loop stacks it over
time.

Every episode runs its whole horizon (static shapes, no data-dependent control flow).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from iap_mjx.es.normalizer import ObsStats, normalize
from iap_mjx.loops import batched_like
from iap_mjx.policies.base import Policy

if TYPE_CHECKING:  # iap_mjx.envs is imported only where an env is built
    from iap_mjx.envs.base import Env, State


class EpisodeResult(struct.PyTreeNode):
    """What one episode reports (a leading batch axis when batched).

    Attributes:
      ret: ``()`` the return.
      steps: ``()`` env steps taken while the episode was live: up to and including the one
        that set ``done`` or met a non-finite reward/observation (a step that diverged was
        still simulated, so the env-step budget counts it; its reward does not).
      bad: ``()`` 1.0 if a non-finite reward/observation was met or the env flagged
        ``metrics["nan_terminations"]``.
      saturated: ``()`` 1.0 if the env flagged ``metrics["contact_saturated"]`` (every contact
        slot filled at some step, so a contact may have been dropped; 0.0 for envs without the
        flag).
      obs_sum, obs_sq_sum: ``(obs_size,)`` sums over the live steps whose reward and
        observation are finite (``(1,)`` zeros when not tracked): ``steps`` also counts a
        diverged step, which these sums leave out (the statistics leave a diverged episode
        out whole: ``normalizer.merge_episodes``).
      metrics: the env's per-episode statistics at the episode's end, ``{name: ()}`` for each
        name in the env's ``episode_metrics`` (e.g. the quadruped course's walls passed; empty
        for envs without them, which then add nothing to the program).
      records: what the ``record`` hook of :func:`run_episode` returned at each step, ``{name:
        (T, ...)}``, and with it ``"alive": (T,)``, 1.0 for the live steps (the tally's own:
        before ``done`` or a non-finite step ended the episode); empty without a hook.
    """

    ret: jax.Array
    steps: jax.Array
    bad: jax.Array
    saturated: jax.Array
    obs_sum: jax.Array
    obs_sq_sum: jax.Array
    metrics: dict[str, jax.Array] = struct.field(default_factory=dict)
    records: dict[str, jax.Array] = struct.field(default_factory=dict)


class Step(struct.PyTreeNode):
    """One env step (one action) as the policy took it.

    Attributes:
      state: the env state whose observation the policy saw.
      seen: that observation as the policy saw it (normalised, see :func:`observe`).
      policy_state: the policy's state before it acted.
      next_state: the env's state after the action.
    """

    state: State
    seen: Any
    policy_state: Any
    next_state: State


class Tally(struct.PyTreeNode):
    """An episode's running sums, each ``()`` unless said.

    Attributes:
      ret: the return of the live steps.
      alive: 1.0 until ``done`` or a non-finite reward/observation, then 0.0 for good; a step
        is live while ``alive`` is 1.0 before it.
      bad: 1.0 once a live step met a non-finite reward/observation or the env flagged
        ``metrics["nan_terminations"]``.
      obs_sum, obs_sq_sum: ``(obs_size,)`` sums of the live steps' raw observations where the
        reward and observation are finite (``(1,)`` zeros when observations are not tracked).
    """

    ret: jax.Array
    alive: jax.Array
    bad: jax.Array
    obs_sum: jax.Array
    obs_sq_sum: jax.Array

    def add(self, step: Step, track_obs: bool) -> tuple[Tally, jax.Array]:
        """This tally with ``step`` added, and ``()`` 1.0 if the step was live (else 0.0).

        A step's reward counts while the episode is alive and the reward and observation are
        finite; a live non-finite one marks the episode bad and ends it, as ``done`` does.
        """
        obs, reward = step.state.obs, step.next_state.reward
        finite = jnp.isfinite(reward) & jnp.all(
            jnp.array([jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves(obs)])
        )
        live = self.alive > 0
        ret = self.ret + jnp.where(live & finite, reward, 0.0)
        bad = jnp.maximum(self.bad, jnp.where(live & ~finite, 1.0, 0.0))
        if "nan_terminations" in step.next_state.metrics:  # the env ended a diverged state itself
            flagged = step.next_state.metrics["nan_terminations"] > 0
            bad = jnp.maximum(bad, jnp.where(live & flagged, 1.0, 0.0))
        obs_sum, obs_sq_sum = self.obs_sum, self.obs_sq_sum
        if track_obs:
            flat = jnp.where(live & finite, jnp.ravel(obs), 0.0)
            obs_sum = obs_sum + flat
            obs_sq_sum = obs_sq_sum + flat**2
        was_live = jnp.where(live, 1.0, 0.0)
        alive = self.alive * (1.0 - step.next_state.done) * jnp.where(finite, 1.0, 0.0)
        return Tally(ret, alive, bad, obs_sum, obs_sq_sum), was_live


def episode_metric_names(env: Env) -> tuple[str, ...]:
    """The names of ``env``'s per-episode statistics in ``State.metrics`` (its
    ``episode_metrics``; none for most envs)."""
    return tuple(getattr(env, "episode_metrics", ()))


def observe(obs_stats: ObsStats | None, obs: Any) -> Any:
    """``obs`` as the policy sees it: normalised by the run's statistics (``None``: as it is)."""
    return obs if obs_stats is None else normalize(obs_stats, obs)


def episode_step(
    env: Env, policy: Policy, params: Any, obs_stats: ObsStats | None, state: State, policy_state: Any
) -> tuple[Step, Any]:
    """One env step from env ``state``: the :class:`Step` taken and the policy's next state."""
    seen = observe(obs_stats, state.obs)
    action, next_policy_state = policy.apply(params, seen, policy_state)
    return Step(state, seen, policy_state, env.step(state, action)), next_policy_state


def run_episode(
    env: Env,
    policy: Policy,
    params: Any,
    key: jax.Array,
    obs_stats: ObsStats | None = None,
    track_obs: bool = False,
    *,
    steps: int | None = None,
    record: Callable[[Step], dict[str, jax.Array]] | None = None,
) -> EpisodeResult:
    """One episode of ``steps`` env steps (default ``env.episode_length``) from
    ``env.reset``, the key split into the reset's and the policy state's.

    Args:
      env, policy, params: the env, the policy and its params (one member, no batch axis).
      key: the episode's PRNG key.
      obs_stats: normalise vector observations before the policy sees them (``None``: raw).
      track_obs: accumulate raw-observation sums for the statistics' next update.
      steps: env steps (actions) to run.
      record: ``Step -> {name: array}`` kept from every step, returned stacked over time in
        ``EpisodeResult.records`` (``(steps, ...)`` each) beside ``"alive"``, which step lived.

    Returns the episode's :class:`EpisodeResult`.
    """
    reset_key, policy_key = jax.random.split(key)
    state = env.reset(reset_key)
    policy_state = policy.initial_state(policy_key)
    obs_size = int(np.prod(env.observation_shape)) if track_obs else 1
    zeros = jnp.zeros((obs_size,), jnp.float32)
    one = jnp.ones((), jnp.float32)
    zero = jnp.zeros((), jnp.float32)
    tally = Tally(ret=zero, alive=one, bad=zero, obs_sum=zeros, obs_sq_sum=zeros)  # alive, nothing added

    def step(carry, _):
        env_state, policy_state, tally = carry
        taken, policy_state = episode_step(env, policy, params, obs_stats, env_state, policy_state)
        tally, live = tally.add(taken, track_obs)
        records = {**record(taken), "alive": live} if record is not None else {}
        return (taken.next_state, policy_state, tally), (live, records)

    carry = batched_like((state, policy_state, tally), key)
    length = env.episode_length if steps is None else steps
    carry, (live, records) = jax.lax.scan(step, carry, None, length=length)
    final, _, tally = carry
    saturated = (
        (final.metrics["contact_saturated"] > 0).astype(jnp.float32) if "contact_saturated" in final.metrics else zero
    )
    metrics = {name: final.metrics[name] for name in episode_metric_names(env)}
    return EpisodeResult(
        tally.ret, jnp.sum(live), tally.bad, saturated, tally.obs_sum, tally.obs_sq_sum, metrics, records
    )
