"""``iap-mjx runs``: the run directories of a folder as a table, read from their files."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from iap_mjx import cli
from iap_mjx.es import checkpoint, listing
from iap_mjx.es.metrics_log import read_history

PRETRAINED = Path(__file__).resolve().parent.parent / "pretrained"


def test_the_shipped_runs_table_is_what_the_command_writes():
    """``pretrained/README.md``'s table is ``iap-mjx runs pretrained``'s: regenerate it after
    exporting a run (the command is in the file)."""
    text = (PRETRAINED / "README.md").read_text()
    section = text.split("<!-- BEGIN runs -->\n", 1)[1].split("\n<!-- END runs -->", 1)[0]
    expected = listing.table([listing.summarise(run) for run in listing.run_dirs(PRETRAINED)], relative_to=PRETRAINED)
    assert section == expected, "pretrained/README.md is stale: iap-mjx runs pretrained --results pretrained/README.md"


def test_a_run_is_summarised_from_its_own_files(tmp_path, capsys):
    """A shipped run copied twice, the copy's config asking for more iterations: the summary's
    checkpoint, stored means and last logged return are the files' own, and the copy shows as
    unfinished; an empty folder and a missing one are refused."""
    source = PRETRAINED / "dcs" / "cheetah-run-seed0"
    shutil.copytree(source, tmp_path / "a" / "done")
    shutil.copytree(source, tmp_path / "b" / "longer")
    config = json.loads((tmp_path / "b" / "longer" / "config.json").read_text())
    config["run"]["iterations"] += 50
    (tmp_path / "b" / "longer" / "config.json").write_text(json.dumps(config))

    found = listing.run_dirs(tmp_path)
    assert found == [tmp_path / "a" / "done", tmp_path / "b" / "longer"]
    done, longer = (listing.summarise(run) for run in found)
    step = checkpoint.latest_step(source)
    stored = json.loads((source / "eval.json").read_text())
    assert done.step == step and done.finished and not longer.finished
    assert done.evaluations == {key.split("@")[0]: float(np.mean(value)) for key, value in stored.items()}
    assert done.eval_return == read_history(source, up_to=step)[-1]["eval_return"]
    assert (done.env, done.policy, done.seed) == ("cheetah-run", "iap", 0)

    assert cli.main(["runs", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 4 and lines[2].startswith("| `a/done` |") and "(unfinished)" in lines[3]
    assert f"train {done.evaluations['train']:.1f}" in lines[2]

    (tmp_path / "empty").mkdir()
    assert cli.main(["runs", str(tmp_path / "empty")]) == 2
    assert "no run directory" in capsys.readouterr().err
    assert cli.main(["runs", str(tmp_path / "missing")]) == 2
    assert "not a directory" in capsys.readouterr().err
