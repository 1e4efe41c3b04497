"""Orbax checkpoints of the whole training state plus the config, in ``RUN_DIR/checkpoints``.

Saves are synchronous and atomic (orbax writes a temporary directory and renames it), so a
run killed at any moment leaves only complete checkpoints behind.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from iap_mjx.es import distributed, metrics_log

logger = logging.getLogger(__name__)

CHECKPOINT_DIR = "checkpoints"


class ShapeMismatch(ValueError):
    """A checkpoint's arrays do not have the shapes of the state it is restored into."""


# the newest checkpoints kept: the latest, and older ones should it have been cut short
MAX_TO_KEEP = 3


def _has_checkpoints(run_dir: str | Path) -> bool:
    return (Path(run_dir) / CHECKPOINT_DIR).is_dir()


def _manager(run_dir: str | Path, *, create: bool = True) -> ocp.CheckpointManager:
    """A manager that knows both items' handlers: without them, orbax logs a warning for
    every item of a checkpoint that it reads (metadata, or a restore of the other item)."""
    options = ocp.CheckpointManagerOptions(max_to_keep=MAX_TO_KEEP, create=create, enable_async_checkpointing=False)
    handlers = {"state": ocp.StandardCheckpointHandler(), "config": ocp.JsonCheckpointHandler()}
    return ocp.CheckpointManager(Path(run_dir).resolve() / CHECKPOINT_DIR, options=options, item_handlers=handlers)


def _reader(run_dir: str | Path) -> ocp.CheckpointManager:
    """A manager that only reads: a missing checkpoint directory raises ``FileNotFoundError``
    (nothing is created, so a mistyped run directory leaves no trace)."""
    if not _has_checkpoints(run_dir):
        raise FileNotFoundError(f"no checkpoint in {Path(run_dir) / CHECKPOINT_DIR}")
    return _manager(run_dir, create=False)


def _step_or_latest(manager: ocp.CheckpointManager, run_dir: str | Path, step: int | None) -> int:
    """``step``, or the newest checkpoint's (``FileNotFoundError`` when there is none)."""
    step = manager.latest_step() if step is None else step
    if step is None:
        raise FileNotFoundError(f"no checkpoint in {Path(run_dir) / CHECKPOINT_DIR}")
    return step


def latest_step(run_dir: str | Path) -> int | None:
    """The iteration of the newest complete checkpoint in ``run_dir``, or ``None``."""
    if not _has_checkpoints(run_dir):
        return None
    with _manager(run_dir, create=False) as manager:
        return manager.latest_step()


def save(run_dir: str | Path, step: int, state: Any, config: dict[str, Any]) -> None:
    """Writes ``state`` (any pytree of arrays) and the JSON ``config`` as checkpoint ``step``."""
    with _manager(run_dir) as manager:
        manager.save(
            step,
            args=ocp.args.Composite(
                state=ocp.args.StandardSave(distributed.to_host(state)),
                config=ocp.args.JsonSave(config),
            ),
            force=True,
        )
        manager.wait_until_finished()
    logger.info("checkpoint %d saved in %s", step, run_dir)


def load_config(run_dir: str | Path, step: int | None = None) -> dict[str, Any]:
    """The JSON config stored with checkpoint ``step`` (default: the latest)."""
    with _reader(run_dir) as manager:
        step = _step_or_latest(manager, run_dir, step)
        restored = manager.restore(step, args=ocp.args.Composite(config=ocp.args.JsonRestore()))
        return dict(restored["config"])


def restore(run_dir: str | Path, like: Any, step: int | None = None) -> tuple[int, Any]:
    """``(step, state)`` restored into the structure, shapes and dtypes of ``like``."""
    with _reader(run_dir) as manager:
        step = _step_or_latest(manager, run_dir, step)
        target = distributed.to_host(like)
        _check_shapes(run_dir, step, target)
        restored = manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(target)))
        return step, restored["state"]


def _leaf_name(path: tuple[Any, ...]) -> str:
    """``strategy_state.mean``-style name of a pytree path, the same for a dataclass's field and
    the dict key orbax stores it under."""
    parts = (getattr(entry, "name", getattr(entry, "key", getattr(entry, "idx", entry))) for entry in path)
    return ".".join(str(part) for part in parts)


def stored_shapes(run_dir: str | Path, step: int) -> dict[str, tuple[int, ...]]:
    """``{leaf name: shape}`` of checkpoint ``step``'s state, read from its metadata (no array
    is loaded)."""
    with _manager(run_dir, create=False) as manager:
        metadata = manager.item_metadata(step)["state"]
    return {_leaf_name(path): tuple(leaf.shape) for path, leaf in jax.tree_util.tree_leaves_with_path(metadata)}


def _check_shapes(run_dir: str | Path, step: int, like: Any) -> None:
    """:class:`ShapeMismatch` when a leaf's stored shape is not ``like``'s, naming the first such leaf
    with both shapes and counting the others: a checkpoint restored into a run built with other
    settings (a policy of another size, a frame another policy input) fails here with the
    sizes, not inside orbax."""
    stored = stored_shapes(run_dir, step)
    wrong = [
        f"{name} {stored[name]} stored, {np.shape(leaf)} built"
        for name, leaf in ((_leaf_name(path), leaf) for path, leaf in jax.tree_util.tree_leaves_with_path(like))
        if name in stored and stored[name] != np.shape(leaf)
    ]
    if wrong:
        more = f" and {len(wrong) - 1} more" if len(wrong) > 1 else ""
        raise ShapeMismatch(
            f"checkpoint {step} in {run_dir} does not fit the run as built: {wrong[0]}{more} (a setting "
            "that sizes the policy or what it sees is not the one the run trained with)"
        )


#: What :func:`export_latest` copies besides the checkpoint: what a person or a resumed run reads.
RUN_FILES = (metrics_log.CONFIG_FILE, metrics_log.METRICS_CSV, metrics_log.METRICS_JSONL, metrics_log.EVAL_FILE)


def export_latest(run_dir: str | Path, dest: str | Path) -> int | None:
    """Copies ``run_dir``'s newest checkpoint and its :data:`RUN_FILES` into ``dest``.

    ``dest`` becomes a run directory of its own with one checkpoint (older ones in it are
    removed): ``iap-mjx eval`` and ``iap-mjx video`` read it, and training resumes from it
    (resuming drops metric rows past the checkpoint). Returns the step copied, or ``None``
    when ``run_dir`` has no checkpoint (nothing is written then).
    """
    run_dir, dest = Path(run_dir), Path(dest)
    step = latest_step(run_dir)
    if step is None:
        return None
    target = dest / CHECKPOINT_DIR
    if not (target / str(step)).is_dir():
        staging = dest / f".{CHECKPOINT_DIR}-{step}.tmp"
        shutil.rmtree(staging, ignore_errors=True)
        shutil.copytree(run_dir / CHECKPOINT_DIR / str(step), staging)
        target.mkdir(parents=True, exist_ok=True)
        staging.replace(target / str(step))
    for old in target.iterdir():
        if old.name != str(step):
            shutil.rmtree(old) if old.is_dir() else old.unlink()
    for name in RUN_FILES:
        if (run_dir / name).exists():
            shutil.copy2(run_dir / name, dest / name)
    logger.info("exported checkpoint %d of %s to %s", step, run_dir, dest)
    return step
