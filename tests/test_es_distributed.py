"""Multi-host training on one machine: two processes (one CPU device each) joined by
``jax.distributed`` with gloo collectives train one population together."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
from test_es_envs import PointMass
from test_es_train import flat, small_config

from iap_mjx.es import train

TESTS = Path(__file__).resolve().parent

CHILD = textwrap.dedent("""
    import json, sys
    sys.path.insert(0, {tests!r})
    import jax
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address="127.0.0.1:{port}", num_processes=2,
                               process_id={process_id})
    assert len(jax.devices()) == 2 and len(jax.local_devices()) == 1
    from test_es_train import small_config, flat
    from test_es_envs import PointMass
    from iap_mjx.es import train
    result = train(small_config(), env=PointMass(), progress=False, run_dir={run_dir!r})
    rows = [dict(iteration=r["iteration"], params_norm=r["params_norm"],
                 return_mean=r["return_mean"]) for r in result.history]
    json.dump(dict(rows=rows, params=flat(result.params).tolist()), open({out!r}, "w"))
""")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_all(children: list[subprocess.Popen]) -> list[int]:
    """The children's exit codes. When one fails its peer would wait for it in a collective
    until the coordinator's own timeout, so the others are killed then (no wall-clock bound:
    a loaded machine only makes the test slower)."""
    while any(child.poll() is None for child in children):
        if any(child.poll() not in (None, 0) for child in children):
            for child in children:
                if child.poll() is None:
                    child.kill()
        time.sleep(0.1)
    return [child.returncode for child in children]


def test_two_processes_train_one_population_and_agree(tmp_path):
    port = free_port()
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=1")
    children = []
    for process_id in range(2):
        code = CHILD.format(
            tests=str(TESTS),
            port=port,
            process_id=process_id,
            run_dir=str(tmp_path / "run"),
            out=str(tmp_path / f"{process_id}.json"),
        )
        children.append(subprocess.Popen([sys.executable, "-c", code], env=env))
    try:
        codes = wait_all(children)
    finally:
        for child in children:
            if child.poll() is None:
                child.kill()
    assert codes == [0, 0]
    results = [json.loads((tmp_path / f"{i}.json").read_text()) for i in range(2)]
    # Both processes hold the same centre after every iteration, and at the end.
    assert results[0]["rows"] == results[1]["rows"]
    np.testing.assert_array_equal(results[0]["params"], results[1]["params"])
    # ...and it is the run one process with two devices computes (up to float rounding).
    local = train(small_config(num_devices=2, checkpoint_every=0), env=PointMass(), progress=False)
    np.testing.assert_allclose(results[0]["params"], flat(local.params), rtol=1e-4, atol=1e-5)
    assert sorted(p.name for p in (tmp_path / "run" / "checkpoints").iterdir()) == ["3", "6"]
