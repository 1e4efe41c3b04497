"""``experiments/reproduce-all.sh``'s steps: ``START`` skips the steps before the one it names
(how a new machine resumes the open runs), and a name that is no step is refused. Run with a
stand-in ``iap-mjx`` that only prints its arguments: nothing trains."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "experiments" / "reproduce-all.sh"


def _run(tmp_path: Path, start: str) -> subprocess.CompletedProcess:
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    stand_in = bin_dir / "iap-mjx"
    stand_in.write_text('#!/bin/sh\necho "iap-mjx $*"\n')
    stand_in.chmod(0o755)
    env = {
        **os.environ,
        "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
        "OUT": str(tmp_path / "out"),
        "START": start,
    }
    return subprocess.run(["bash", str(SCRIPT)], env=env, capture_output=True, text=True, cwd=SCRIPT.parent.parent)


def test_every_listed_step_guards_one_block_in_order():
    text = SCRIPT.read_text()
    listed = re.search(r'^STEPS="([^"]+)"', text, re.M).group(1).split()
    assert re.findall(r"^if step ([\w-]+); then$", text, re.M) == listed


def test_start_skips_the_steps_before_it(tmp_path):
    result = _run(tmp_path, "table1-cnn")
    assert result.returncode == 0, result.stderr
    calls = [line for line in result.stdout.splitlines() if line.startswith("iap-mjx ")]
    assert calls[0].startswith("iap-mjx reproduce table1 ") and "--policy cnn" in calls[0]
    skipped = ("fig7", "table2", "--tasks reacher-easy,ball_in_cup-catch,walker-walk")  # table1-rest's
    assert not any(word in call for call in calls for word in skipped)
    second = [i for i, call in enumerate(calls) if "--out " + str(tmp_path / "out" / "table1-fs2") in call]
    gates = [i for i, call in enumerate(calls) if call.startswith("iap-mjx reproduce gates ")]
    assert len(second) == 2 and len(gates) == 1 and gates[0] < second[0]  # gates, then Table 1's second setting
    assert "env.frame_stack=2 policy.with_patches=true" in calls[second[0]] and "--policy cnn" in calls[second[1]]
    assert "--section fig11-turn" in calls[-1]  # the last step ran: step fig11-turn's command again
    turn = _run(tmp_path, "fig11-turn")
    assert [line for line in turn.stdout.splitlines() if line.startswith("iap-mjx ")][0] == calls[-1]
    assert "== skipped step table1-rest (START=table1-cnn)" in result.stdout
    assert result.stderr == ""  # no Figure 11 runs to copy: nothing tried on the bare pattern


@pytest.mark.parametrize("start", ["table3", "fig7 fig8", " "])
def test_a_start_that_is_no_step_is_refused_before_anything_runs(tmp_path, start):
    result = _run(tmp_path, start)
    assert result.returncode == 2
    assert "is not a step; valid: table1-first fig7" in result.stderr
    assert "iap-mjx" not in result.stdout
