"""Population evaluation: ``lax.scan`` over time, ``vmap`` over episodes, chunked and sharded.

Every episode runs the env's full horizon (static shapes, no data-dependent control flow);
rewards after ``done`` are masked out. Episodes are independent, so the flat list of
``members x episodes`` is split over devices (``shard_map`` on a 1-D mesh named ``"pop"``)
and, on each device, into chunks of ``chunk_size`` that one ``vmap`` simulates together while
``lax.map`` walks the chunks. Keys are drawn per episode before the split, so results do not
depend on the device count or chunk size (beyond float rounding).
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from iap_mjx.chunks import repeat_row
from iap_mjx.es.normalizer import ObsStats, normalize
from iap_mjx.loops import batched_like
from iap_mjx.policies.base import Policy

POP_AXIS = "pop"


@dataclasses.dataclass(frozen=True)
class EpisodeResult:
    """What one episode reports (a leading batch axis when batched).

    ``ret`` ``()`` the return, ``steps`` ``()`` control steps before ``done``, ``bad``
    ``()`` 1.0 if a non-finite reward/observation was met or the env flagged
    ``metrics["nan_terminations"]``, ``saturated`` ``()`` 1.0 if the env flagged
    ``metrics["contact_saturated"]`` (every contact slot filled at some step, so a contact
    may have been dropped; 0.0 for envs without the flag), ``obs_sum``/``obs_sq_sum``
    ``(obs_size,)`` sums over the live steps (zeros when not tracked), ``metrics`` the
    env's per-episode statistics at the episode's end: ``{name: ()}`` for each name in the
    env's ``episode_metrics`` (e.g. the quadruped course's walls passed; empty for envs
    without them, which then add nothing to the program).
    """

    ret: jax.Array
    steps: jax.Array
    bad: jax.Array
    saturated: jax.Array
    obs_sum: jax.Array
    obs_sq_sum: jax.Array
    metrics: dict[str, jax.Array] = dataclasses.field(default_factory=dict)


jax.tree_util.register_dataclass(
    EpisodeResult,
    data_fields=["ret", "steps", "bad", "saturated", "obs_sum", "obs_sq_sum", "metrics"],
    meta_fields=[],
)


def episode_metric_names(env: Any) -> tuple[str, ...]:
    """The names of ``env``'s per-episode statistics in ``State.metrics`` (its
    ``episode_metrics``; none for most envs)."""
    return tuple(getattr(env, "episode_metrics", ()))


def run_episode(
    env: Any,
    policy: Policy,
    params: Any,
    key: jax.Array,
    obs_stats: ObsStats | None,
    track_obs: bool,
) -> EpisodeResult:
    """One episode of ``env.episode_length`` control steps from ``env.reset(key)``.

    ``obs_stats`` (or ``None``) normalises vector observations before the policy sees them;
    ``track_obs`` accumulates raw-observation sums for the statistics' next update.
    """
    reset_key, policy_key = jax.random.split(key)
    state = env.reset(reset_key)
    policy_state = policy.initial_state(policy_key)
    obs_size = int(np.prod(env.observation_shape)) if track_obs else 1
    zeros = jnp.zeros((obs_size,), jnp.float32)

    def step(carry, _):
        env_state, policy_state, ret, alive, bad, obs_sum, obs_sq_sum = carry
        obs = env_state.obs
        seen = obs if obs_stats is None else normalize(obs_stats, obs)
        action, policy_state = policy.apply(params, seen, policy_state)
        next_state = env.step(env_state, action)
        reward = next_state.reward
        finite = jnp.isfinite(reward) & jnp.all(
            jnp.array([jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves(obs)])
        )
        live = alive > 0
        ret = ret + jnp.where(live & finite, reward, 0.0)
        bad = jnp.maximum(bad, jnp.where(live & ~finite, 1.0, 0.0))
        if "nan_terminations" in next_state.metrics:  # the env ended a diverged state itself
            flagged = next_state.metrics["nan_terminations"] > 0
            bad = jnp.maximum(bad, jnp.where(live & flagged, 1.0, 0.0))
        if track_obs:
            flat = jnp.where(live & finite, jnp.ravel(obs), 0.0)
            obs_sum = obs_sum + flat
            obs_sq_sum = obs_sq_sum + flat**2
        steps_alive = jnp.where(live, 1.0, 0.0)
        alive = alive * (1.0 - next_state.done) * jnp.where(finite, 1.0, 0.0)
        return (next_state, policy_state, ret, alive, bad, obs_sum, obs_sq_sum), steps_alive

    one = jnp.ones((), jnp.float32)
    zero = jnp.zeros((), jnp.float32)
    carry = batched_like((state, policy_state, zero, one, zero, zeros, zeros), key)
    carry, steps_alive = jax.lax.scan(step, carry, None, length=env.episode_length)
    final, _, ret, _, bad, obs_sum, obs_sq_sum = carry
    saturated = (final.metrics["contact_saturated"] > 0).astype(jnp.float32) \
        if "contact_saturated" in final.metrics else zero
    metrics = {name: final.metrics[name] for name in episode_metric_names(env)}
    return EpisodeResult(ret, jnp.sum(steps_alive), bad, saturated, obs_sum, obs_sq_sum, metrics)


def make_mesh(num_devices: int = 0, devices: Any = None) -> Mesh:
    """A 1-D mesh named ``"pop"`` over the first ``num_devices`` of ``devices`` (all if 0)."""
    devices = list(jax.devices() if devices is None else devices)
    if num_devices:
        if num_devices > len(devices):
            raise ValueError(
                f"run.num_devices = {num_devices} but only {len(devices)} devices exist"
            )
        devices = devices[:num_devices]
    return Mesh(np.array(devices), (POP_AXIS,))


def make_evaluator(
    env: Any,
    policy: Policy,
    unravel: Callable[[jax.Array], Any],
    mesh: Mesh,
    chunk_size: int,
    track_obs: bool,
) -> Callable[..., EpisodeResult]:
    """``evaluate(flat_params (N, D), keys (N, 2), obs_stats) -> EpisodeResult`` with ``(N,)``.

    Row ``i`` is one episode of the policy with flat params ``flat_params[i]`` from
    ``keys[i]``. ``N`` is padded internally (repeating row 0) so that every device gets the
    same number of equal chunks: a ragged last chunk would make XLA compile the episode a
    second time. Call it inside ``jit``.
    """
    num_devices = mesh.devices.size

    def local(flat_params, keys, obs_stats):
        def one(args):
            flat, key = args
            return run_episode(env, policy, unravel(flat), key, obs_stats, track_obs)

        per_device = flat_params.shape[0]
        batch = per_device // -(-per_device // chunk_size)
        return jax.lax.map(one, (flat_params, keys), batch_size=batch)

    replicated = PartitionSpec()
    sharded = jax.shard_map(
        local,
        mesh=mesh,
        in_specs=(PartitionSpec(POP_AXIS), PartitionSpec(POP_AXIS), replicated),
        out_specs=PartitionSpec(POP_AXIS),
        check_vma=False,
    )

    def evaluate(flat_params, keys, obs_stats):
        n = flat_params.shape[0]
        padded = num_devices * padded_share(n, num_devices, chunk_size)
        if padded != n:
            pad = partial(repeat_row, row=0, count=padded - n)
            flat_params, keys = pad(flat_params), pad(keys)
        spec = NamedSharding(mesh, PartitionSpec(POP_AXIS))
        flat_params = jax.lax.with_sharding_constraint(flat_params, spec)
        keys = jax.lax.with_sharding_constraint(keys, spec)
        result = sharded(flat_params, keys, obs_stats)
        return jax.tree_util.tree_map(lambda x: x[:n], result)

    return evaluate


def padded_share(n: int, num_devices: int, chunk_size: int) -> int:
    """Episodes per device after padding ``n`` to equal shares of equal chunks."""
    share = -(-n // num_devices)
    chunks = -(-share // chunk_size)
    return chunks * -(-share // chunks)
