"""``iap-mjx reproduce fig8``: curves on a wall-clock axis built from the timings file, brute
force at ``p = 2`` projected from the same timings; bad input fails before anything compiles.
Training is ``iap_mjx.paper.report_runs``'s (tested elsewhere): finished runs are written by hand."""

from __future__ import annotations

import json

import numpy as np
import pytest

from iap_mjx import cli, configs
from iap_mjx.es import checkpoint
from iap_mjx.es.metrics_log import MetricsWriter
from iap_mjx.paper import fig8

ITERATIONS = ("run.iterations=3",)


def _fake_run(out, kernel, patch, returns):
    config = configs.apply_overrides(configs.get(fig8.PRESET), (*ITERATIONS, *fig8.variant_overrides(kernel, patch)))
    run_dir = out / f"{fig8.variant_name(kernel, patch)}-seed0"
    writer = MetricsWriter(run_dir, 0, tensorboard=False)
    for i, value in enumerate(returns, start=1):
        writer.write({"iteration": i, "eval_return": value, "run_s": 99.0, "compile_s": 99.0, "env_steps": 1000 * i})
    checkpoint.save(run_dir, len(returns), {"x": np.zeros(2)}, config.to_dict())


def _timings():
    variants = {
        fig8.variant_name(k, p): {"iteration_s": 2.0 * p + (k == "brute"), "compile_s": 30.0, "iterations_timed": 2}
        for k, p in fig8.VARIANTS
    }
    return {
        "variants": variants,
        "machine": "test",
        "started": "now",
        "compile": "persistent compilation cache off",
        "brute_p2": {
            "forward_pass_s": 2.0,
            "hybrid_forward_pass_s": 0.001,
            "frames_per_iteration": 8500,
            "projected_iteration_s": 4.0 + 8500 * 1.999,
        },
    }


def test_bad_settings_fail_before_anything_runs(tmp_path, capsys):
    with pytest.raises(ValueError, match="policy.kernel"):
        fig8.reproduce_fig8(tmp_path, overrides=("policy.kernel=relu",))
    with pytest.raises(ValueError, match="heigth"):
        fig8.reproduce_fig8(tmp_path, overrides=("env.heigth=64",))
    with pytest.raises(ValueError, match="machine alone"):
        fig8.reproduce_fig8(tmp_path, train=False)  # reporting never measures
    assert not list(tmp_path.iterdir())
    assert cli.main(["reproduce", "fig8", "policy.patch_size=4", "--out", str(tmp_path)]) == 2
    assert "policy.patch_size" in capsys.readouterr().err


def test_frames_per_iteration_counts_the_population_and_the_evaluation():
    config = configs.get(fig8.PRESET)
    assert config.es.population_size == 64 and config.run.eval_episodes == 4 and config.es.n_episodes == 1
    assert fig8.frames_per_iteration(config) == 68 * 125  # 1000 control steps / action repeat 8
    twice = configs.apply_overrides(config, ("es.n_episodes=2", "env.episode_length=10"))
    assert fig8.frames_per_iteration(twice) == (128 + 4) * 10


def test_curves_use_the_measured_seconds_per_iteration_not_the_runs_own(tmp_path):
    (tmp_path / fig8.TIMINGS_FILE).write_text(json.dumps(_timings()))
    _fake_run(tmp_path, "brute", 8, [1.0, 2.0, 3.0])
    _fake_run(tmp_path, "hybrid", 2, [5.0, 7.0])  # unfinished: reported as far as it got
    markdown = fig8.reproduce_fig8(tmp_path, overrides=ITERATIONS, train=False, results=tmp_path / "RESULTS.md")
    rows = {
        line.split(" | ")[0]: line
        for line in markdown.splitlines()
        if line.startswith("| IAP") or line.startswith("| brute")
    }
    assert rows["| brute-force softmax"].endswith("| 8 | 1,200 | 17.0 | 30 | 3 | 3.0 | 3.0 | 81 |")
    assert rows["| IAP hybrid (10,5)"].endswith("| 2 | 19,200 | 4.0 | 30 | 2 | 7.0 | 7.0 | 38 |")
    assert len(rows) == 2
    assert "**4,249x** hybrid's measured 4.0 s" in markdown
    stored = json.loads((tmp_path / "fig8.json").read_text())
    assert np.allclose(fig8.wall_seconds(stored["rows"][0]), [47.0, 64.0, 81.0])
    assert (tmp_path / "fig8.png").stat().st_size > 0
    assert "<!-- BEGIN fig8 -->" in (tmp_path / "RESULTS.md").read_text()
    kept = tmp_path / "experiments" / "fig8" / fig8.TIMINGS_FILE  # tracked beside the figure
    assert json.loads(kept.read_text()) == _timings()
