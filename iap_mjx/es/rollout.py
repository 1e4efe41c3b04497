"""Population evaluation: :func:`iap_mjx.es.episode.run_episode` ``vmap``-ed over episodes,
chunked and sharded.

Episodes are independent, so the flat list of ``members x episodes`` is split over devices
(``shard_map`` on a 1-D mesh named ``"pop"``) and, on each device, into the fewest equal
chunks of at most ``chunk_size`` episodes (``ceil(share / chunk_size)`` chunks, the share padded
to a multiple of their number), each simulated by one ``vmap`` while ``lax.map`` walks the
chunks: 68 episodes on 2 devices with ``chunk_size=64`` make one chunk of 34 per device. Keys
are drawn per episode before the split, so results do not depend on the device count or chunk
size (beyond float rounding).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from iap_mjx.chunks import ceil_div, repeat_row
from iap_mjx.es.episode import EpisodeResult, run_episode
from iap_mjx.policies.base import Policy

if TYPE_CHECKING:  # iap_mjx.envs is imported only where an env is built
    from iap_mjx.envs.base import Env

POP_AXIS = "pop"


def make_mesh(num_devices: int = 0, devices: Any = None) -> Mesh:
    """A 1-D mesh named ``"pop"`` over the first ``num_devices`` of ``devices`` (all if 0)."""
    devices = list(jax.devices() if devices is None else devices)
    if num_devices:
        if num_devices > len(devices):
            raise ValueError(f"run.num_devices = {num_devices} but only {len(devices)} devices exist")
        devices = devices[:num_devices]
    return Mesh(np.array(devices), (POP_AXIS,))


def make_rollout(
    env: Env,
    policy: Policy,
    unravel: Callable[[jax.Array], Any],
    mesh: Mesh,
    chunk_size: int,
    track_obs: bool,
) -> Callable[..., EpisodeResult]:
    """``rollout(flat_params (N, D), keys (N, 2), obs_stats) -> EpisodeResult`` with ``(N,)``.

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

        # ``rollout`` padded the rows to a whole number of equal chunks of at most
        # ``chunk_size`` (:func:`padded_share`), so this chunk divides them exactly
        per_device = flat_params.shape[0]
        chunk = per_device // ceil_div(per_device, chunk_size)
        return jax.lax.map(one, (flat_params, keys), batch_size=chunk)

    replicated = PartitionSpec()
    sharded = jax.shard_map(
        local,
        mesh=mesh,
        in_specs=(PartitionSpec(POP_AXIS), PartitionSpec(POP_AXIS), replicated),
        out_specs=PartitionSpec(POP_AXIS),
        check_vma=False,
    )

    def rollout(flat_params, keys, obs_stats):
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

    return rollout


def padded_share(n: int, num_devices: int, chunk_size: int) -> int:
    """Episodes per device after padding ``n`` to equal shares of equal chunks."""
    share = ceil_div(n, num_devices)
    chunks = ceil_div(share, chunk_size)
    return chunks * ceil_div(share, chunks)
