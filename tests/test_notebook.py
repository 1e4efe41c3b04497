"""The quickstart notebook runs top to bottom and shows a curve, a video, distracted frames and a
shipped trained policy's strip.

Its budget (8 members, 60-step episodes, 2 evaluation episodes) is ``tests/test_first_run.py``'s,
which runs first: the notebook's ES iteration and video load from the compilation cache.
"""

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parent.parent / "notebooks" / "quickstart.ipynb"


def test_notebook_budget_is_the_first_run_tests():
    """The notebook's overrides that shape its programs are ``test_first_run``'s, so that the
    notebook (scheduled last) loads them from the compilation cache instead of compiling."""
    from test_first_run import BUDGET, EPISODE_STEPS

    source = "".join(
        "".join(cell.source) for cell in nbformat.read(NOTEBOOK, as_version=4).cells if cell.cell_type == "code"
    )
    for setting in BUDGET:
        if not setting.startswith(("run.iterations", "run.checkpoint_every")):  # host-side only
            assert f'"{setting}"' in source, setting
    assert f"steps={EPISODE_STEPS})" in source  # the video: the CLI records a whole episode


@pytest.mark.last  # compiles what test_first_run compiles: loads it from the cache
def test_quickstart_notebook_executes(tmp_path, monkeypatch):
    # the kernel inherits this: it compiles into the tests' cache, not the user's
    monkeypatch.setenv("IAP_MJX_CACHE_DIR", str(NOTEBOOK.parent.parent / ".jax_cache"))
    # JAX's default partitioner, as a user runs it and as test_first_run compiled the programs
    monkeypatch.delenv("JAX_USE_SHARDY_PARTITIONER", raising=False)
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    # a probe cell after the notebook's own: the partitioner its kernel ran with
    notebook.cells.append(nbformat.v4.new_code_cell("print(jax.config.jax_use_shardy_partitioner)"))
    # no per-cell time limit (nbclient's default is 30 s): a loaded machine only makes it slower
    NotebookClient(
        notebook, timeout=None, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    ).execute()
    images = [
        output
        for cell in notebook.cells
        if cell.cell_type == "code"
        for output in cell.get("outputs", [])
        if "image/png" in output.get("data", {}) or "image/gif" in output.get("data", {})
    ]
    (probe,) = notebook.cells[-1].outputs
    assert probe["text"].strip() == "True"  # Shardy, JAX's default, as a user's kernel runs it
    assert len(images) == 4  # the reward curve, the episode, distracted first frames, the trained policy
    assert (tmp_path / "runs" / "notebook" / "episode.gif").stat().st_size > 1000
    assert (tmp_path / "runs" / "notebook" / "distracted.png").stat().st_size > 1000
    # the shipped cheetah runs on a held-out background: its 20 evaluation episodes there score
    # 75-299 (eval.json), an untrained policy 1-2 (RESULTS.md, the first run's first evaluation)
    (returned,) = [line for line in _stdout(notebook.cells[-2]) if line.startswith("return over the episode")]
    assert float(returned.split(": ")[1]) > 20
    assert (tmp_path / "runs" / "notebook" / "trained-held-out.png").stat().st_size > 1000


def _stdout(cell) -> list[str]:
    """The lines a code cell printed."""
    return [line for output in cell.outputs if output.get("name") == "stdout" for line in output["text"].splitlines()]
