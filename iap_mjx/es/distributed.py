"""Multi-host training: join several processes into one JAX runtime over CPU collectives, and
read a replicated array's local copy on the host (:func:`to_host`).

Every process runs the same ``train`` call; ``jax.devices()`` then lists the devices of all
processes, the population mesh spans them, and each process simulates its share of the
population while the update (replicated) keeps every process's centre identical.

On a cluster, start one process per machine (or per socket), e.g. with two machines:

    # on node0 (the coordinator, reachable from every node on PORT):
    iap-mjx train cheetah-run-state --coordinator node0:12345 --num-processes 2 --process-id 0
    # on node1:
    iap-mjx train cheetah-run-state --coordinator node0:12345 --num-processes 2 --process-id 1

Use the same preset, overrides and ``--run-dir`` (on a shared filesystem) everywhere;
process 0 writes the metrics, all processes take part in writing checkpoints. Under SLURM,
``--process-id $SLURM_PROCID --num-processes $SLURM_NTASKS`` fills these in. Each process
should set its own CPU split (``XLA_FLAGS=--xla_force_host_platform_device_count=N``, the
CLI's default is one device per core). ``run.max_minutes`` is refused with several processes
(their clocks could disagree on when to stop).
"""

from __future__ import annotations

import logging
from typing import Any

import jax
import numpy as np

from iap_mjx.checks import require_int

logger = logging.getLogger(__name__)


def initialize(coordinator_address: str, num_processes: int, process_id: int) -> None:
    """Joins this process to a multi-process JAX runtime with gloo CPU collectives.

    Must run before JAX computes anything in this process.
    """
    require_int("num_processes", num_processes)
    require_int("process_id", process_id, 0)
    if process_id >= num_processes:
        raise ValueError(f"process_id = {process_id} must be in [0, num_processes = {num_processes})")
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(
        coordinator_address=coordinator_address,
        num_processes=num_processes,
        process_id=process_id,
    )
    logger.info(
        "process %d of %d joined %s; %d devices in all",
        process_id,
        num_processes,
        coordinator_address,
        len(jax.devices()),
    )


def to_host(tree: Any) -> Any:
    """Numpy copies of a pytree of replicated (possibly multi-process) arrays: each array's
    first local copy, so a sharded array gives only its first local shard (replicate it
    first, as ``iap_mjx.es.results.evaluate_run_episodes`` does)."""
    return jax.tree_util.tree_map(
        lambda x: np.asarray(x.addressable_data(0)) if isinstance(x, jax.Array) else np.asarray(x), tree
    )
