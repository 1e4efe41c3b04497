"""Large batches of envs: chunked ``vmap`` (``lax.map`` over chunks) and device sharding.

One ``vmap`` over a thousand MJX envs is a program large enough to hang XLA's CPU runtime; a
``lax.map`` over chunks of at most ``chunk_size`` envs compiles the per-chunk program once and
runs the chunks one after another, which bounds both memory and the size of what XLA
schedules.
``shard`` splits the batch axis over devices with ``shard_map`` first (each device then
chunks its share). Benchmarks batch env programs with these; an episode of a policy is
``iap_mjx.es.episode.run_episode``, which ``iap_mjx.es.rollout`` batches over a population.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, PartitionSpec

from iap_mjx.checks import require_int
from iap_mjx.chunks import map_chunks

BATCH_AXIS = "batch"


def chunked_vmap(fn: Callable[..., Any], chunk_size: int) -> Callable[..., Any]:
    """``vmap(fn)`` evaluated ``chunk_size`` rows at a time (:func:`iap_mjx.chunks.map_chunks`).

    The returned function takes pytrees whose leaves share a leading axis of size ``n`` (``n``
    a multiple of ``chunk_size``, or at most ``chunk_size``: a benchmark times whole chunks)
    and returns ``vmap(fn)(*args)``, computed as ``n / chunk_size`` sequential chunks.
    """
    require_int("chunk_size", chunk_size)
    batched = jax.vmap(fn)

    def run(*args: Any) -> Any:
        sizes = {leaf.shape[0] for leaf in jax.tree.leaves(args)}
        if len(sizes) != 1:
            raise ValueError(f"all leaves need the same leading (batch) axis, got sizes {sizes}.")
        (n,) = sizes
        if n <= chunk_size:
            return batched(*args)
        if n % chunk_size:
            raise ValueError(f"batch size {n} is not a multiple of chunk_size={chunk_size}.")
        return map_chunks(lambda chunk: batched(*chunk), args, chunk_size, n)

    return run


def shard(fn: Callable[..., Any], mesh: Mesh | None = None) -> Callable[..., Any]:
    """``fn`` (batched over a leading axis) run with that axis split over ``mesh``'s devices.

    ``mesh`` is a 1-D mesh with axis ``BATCH_AXIS`` (default: all of ``jax.devices()``);
    the batch size must be a multiple of the device count. ``check_vma=False`` because
    MJX's internals are not annotated for varying-manual-axes checking.
    """
    mesh = mesh if mesh is not None else Mesh(np.array(jax.devices()), (BATCH_AXIS,))
    spec = PartitionSpec(BATCH_AXIS)
    return jax.shard_map(fn, mesh=mesh, in_specs=spec, out_specs=spec, check_vma=False)
