"""``iap-mjx runs``: the run directories of a folder as a table, read from their files."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from iap_mjx import cli, sections
from iap_mjx.configs.training import EVAL_SEED
from iap_mjx.es import checkpoint, listing
from iap_mjx.es.metrics_log import METRICS_JSONL, evaluation_key, parse_evaluation_key, read_history

PRETRAINED = Path(__file__).resolve().parent.parent / "pretrained"


def test_the_shipped_runs_table_is_what_the_command_writes():
    """``pretrained/README.md``'s table is ``iap-mjx runs pretrained``'s: regenerate it after
    exporting a run (the command is in the file)."""
    section = sections.read_section(PRETRAINED / "README.md", "runs")
    assert section is not None, "pretrained/README.md has no runs section"
    expected = listing.table([listing.listed(run) for run in listing.run_dirs(PRETRAINED)], relative_to=PRETRAINED)
    assert section == expected, "pretrained/README.md is stale: iap-mjx runs pretrained --results pretrained/README.md"


def test_evaluation_keys_round_trip_and_others_are_refused():
    assert parse_evaluation_key(evaluation_key("held-out", 100, 20, EVAL_SEED)) == ("held-out", 100, 20, EVAL_SEED)
    assert parse_evaluation_key("course-eyes-closed@200x20s-3") == ("course-eyes-closed", 200, 20, -3)
    for key in ("train", "train@100", "train@100x20", "@100x20s1", "train@100x20s1x"):
        with pytest.raises(ValueError, match="not an evaluation key"):
            parse_evaluation_key(key)


def _stored_means(path: Path) -> dict:
    return {
        key: float(np.mean(value["return"] if isinstance(value, dict) else value))
        for key, value in json.loads(path.read_text()).items()
    }


def test_a_run_is_listed_from_its_own_files(tmp_path, capsys):
    """Shipped runs copied and altered: a Table 1 run whose eval.json also holds an older
    checkpoint's entry, a shorter evaluation and another seed's (all three left out); the same
    run asking for more iterations and without metrics (unfinished, no parameters, no logged
    return); a blind quadruped run (its course entry is a dict); a run before its first
    checkpoint. An empty folder, a missing one and a broken eval.json are refused by name."""
    dcs, blind = PRETRAINED / "dcs" / "cheetah-run-seed0", PRETRAINED / "quadruped" / "quadruped-walls-blind-seed0"
    shutil.copytree(dcs, tmp_path / "a" / "done")
    shutil.copytree(dcs, tmp_path / "b" / "longer")
    shutil.copytree(blind, tmp_path / "c" / "blind")
    step = checkpoint.latest_step(dcs)
    original = json.loads((dcs / "eval.json").read_text())
    train = next(key for key in original if key.startswith("train@"))
    extra = {
        evaluation_key("train", step - 10, 20, EVAL_SEED): [1000.0] * 20,
        evaluation_key("train", step, 5, EVAL_SEED): [1000.0] * 5,
        evaluation_key("train", step, 20, EVAL_SEED + 1): [1000.0] * 20,
    }
    (tmp_path / "a" / "done" / "eval.json").write_text(json.dumps({**original, **extra}))
    config = json.loads((tmp_path / "b" / "longer" / "config.json").read_text())
    config["run"]["iterations"] += 50
    (tmp_path / "b" / "longer" / "config.json").write_text(json.dumps(config))
    (tmp_path / "b" / "longer" / METRICS_JSONL).unlink()

    found = listing.run_dirs(tmp_path)
    assert found == [tmp_path / "a" / "done", tmp_path / "b" / "longer", tmp_path / "c" / "blind"]
    done, longer, quadruped = (listing.listed(run) for run in found)
    means = _stored_means(dcs / "eval.json")
    assert done.step == step and done.finished and not longer.finished
    assert done.evaluations["train"] == (means[train], 20)
    assert {name: mean for name, (mean, _) in done.evaluations.items()} == {
        key.split("@")[0]: mean for key, mean in means.items()
    }
    assert done.eval_return == read_history(dcs, up_to=step)[-1]["eval_return"] and done.parameters > 0
    assert (done.env, done.policy, done.seed) == ("cheetah-run", "iap", 0)
    assert longer.parameters is None and longer.eval_return is None
    course = {key.split("@")[0]: mean for key, mean in _stored_means(blind / "eval.json").items()}
    assert quadruped.policy == "hierarchical (iap, blind)"
    assert {name: mean for name, (mean, _) in quadruped.evaluations.items()} == course

    assert cli.main(["runs", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 5 and lines[2].startswith("| `a/done` |") and "(unfinished)" in lines[3]
    assert f"train {means[train]:.1f}" in lines[2] and "(20 each)" in lines[2]
    assert cli.main(["runs", str(tmp_path / "a" / "done")]) == 0  # a run directory itself, by its name
    assert capsys.readouterr().out.splitlines()[2].startswith("| `done` |")

    (tmp_path / "d" / "started").mkdir(parents=True)  # a run before its first checkpoint
    shutil.copy(dcs / "config.json", tmp_path / "d" / "started" / "config.json")
    started = listing.listed(tmp_path / "d" / "started")
    assert started.step is None and not started.finished and started.evaluations == {} and started.eval_return is None
    assert cli.main(["runs", str(tmp_path / "d")]) == 0
    iterations = json.loads((dcs / "config.json").read_text())["run"]["iterations"]
    assert f"| none yet / {iterations} (unfinished) |" in capsys.readouterr().out.splitlines()[2]

    (tmp_path / "c" / "blind" / "eval.json").write_text(json.dumps({"course": [1.0]}))
    assert cli.main(["runs", str(tmp_path)]) == 2
    assert "eval.json: not a run's evaluations" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert cli.main(["runs", str(tmp_path / "empty")]) == 2
    assert "no run directory" in capsys.readouterr().err
    assert cli.main(["runs", str(tmp_path / "missing")]) == 2
    assert "not a directory" in capsys.readouterr().err
