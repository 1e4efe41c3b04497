"""Evaluations of a run's checkpoint kept in its run directory (``eval.json``), so that a report
(``reproduce table1``, ``fig7``, ``fig11``, ``table2``) reads them instead of evaluating again.

``eval.json`` maps a key (:func:`eval_key`: what was evaluated, the checkpoint, the number
of episodes and the seed) to a list of per-episode returns, or to a dict of per-episode lists
(``"return"`` and an env's course statistics).
"""

from __future__ import annotations

import functools
import json
import logging
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from iap_mjx.configs.training import EVAL_SEED
from iap_mjx.es import metrics_log
from iap_mjx.es.metrics_log import EVAL_FILE
from iap_mjx.files import write_json

logger = logging.getLogger(__name__)

COURSE_KEY = "course"  # the eval.json entry of a quadruped run on its training env's course, unseen draws
EYES_CLOSED_OVERRIDES = ("policy.blind=true",)  # the condition: the trained high level given a zeroed image
EYES_CLOSED_KEY = "course-eyes-closed"  # its eval.json entry


def eval_key(name: str, step: int, episodes: int) -> str:
    """The ``eval.json`` key of evaluation ``name`` of checkpoint ``step`` on ``episodes``
    episodes drawn from the tables' seed, :data:`EVAL_SEED` (``metrics_log.evaluation_key``)."""
    return metrics_log.evaluation_key(name, step, episodes, EVAL_SEED)


def episode_count(entry: Any) -> int:
    """The episodes an ``eval.json`` entry holds (a list of returns, or a dict with ``"return"``)."""
    return len(metrics_log.entry_returns(entry))


def stored_evaluation(run_dir: Path, key: str, episodes: int, evaluate: Callable[[], Any]) -> Any:
    """``run_dir/eval.json``'s entry ``key`` where it holds ``episodes`` episodes; otherwise
    ``evaluate()``'s (a JSON value of that form), stored under ``key`` first.

    An entry with another number of episodes is evaluated again. The file is replaced whole, so
    a killed report never leaves it cut short.
    """
    path = Path(run_dir) / EVAL_FILE
    stored = json.loads(path.read_text()) if path.exists() else {}
    if key not in stored or episode_count(stored[key]) != episodes:
        logger.info("%s: evaluating %s", Path(run_dir).name, key)
        stored[key] = evaluate()
        write_json(path, stored)
    return stored[key]


def evaluate_conditions(
    run_dir: Path, step: int, *, episodes: int, conditions: dict[str, tuple[str, ...]]
) -> dict[str, list[float]]:
    """``{name: returns}`` of the run's checkpoint ``step`` under each of ``conditions``
    (``{name: env overrides}``, e.g. :data:`iap_mjx.paper.table1.CONDITIONS`), ``episodes``
    episodes drawn from :data:`EVAL_SEED`; read from ``eval.json`` where stored, evaluated (and
    stored) otherwise."""
    from iap_mjx import es

    def evaluate(condition: tuple[str, ...]) -> list[float]:
        returns = es.evaluate_run(run_dir, episodes=episodes, seed=EVAL_SEED, overrides=condition)
        return [float(r) for r in returns]

    return {
        name: stored_evaluation(
            run_dir, eval_key(name, step, episodes), episodes, functools.partial(evaluate, condition)
        )
        for name, condition in conditions.items()
    }


def evaluate_course(
    run_dir: Path, step: int, *, episodes: int, eyes_closed: bool = False, courses_of: int | None = None
) -> dict[str, list[float]]:
    """``{"return": (episodes,), statistic: (episodes,) ...}`` (lists) of the quadruped run's
    checkpoint ``step`` on fresh courses (with ``eyes_closed``, the same courses, its high level
    given a zeroed image), ``episodes`` episodes drawn from :data:`EVAL_SEED` and the checkpoint's
    iteration, or with ``courses_of`` from iteration ``courses_of``'s (the courses another budget's
    report played: ``es.evaluate_run_episodes(..., episodes_of=...)``); read from ``eval.json``
    where stored (under its own key when ``courses_of`` is another iteration), evaluated (and
    stored) otherwise. Figure 11's and Table 2's."""
    from iap_mjx import es

    condition = EYES_CLOSED_OVERRIDES if eyes_closed else ()
    other = courses_of is not None and courses_of != step

    def evaluate() -> dict[str, list[float]]:
        results = es.evaluate_run_episodes(
            run_dir, episodes=episodes, seed=EVAL_SEED, overrides=condition, episodes_of=courses_of if other else None
        )
        return {name: [float(value) for value in values] for name, values in results.items()}

    name = EYES_CLOSED_KEY if eyes_closed else COURSE_KEY
    key = eval_key(f"{name}-of{courses_of}" if other else name, step, episodes)
    return stored_evaluation(run_dir, key, episodes, evaluate)


def seed_means(rows: list[dict[str, Any]], entry: str, names: Iterable[str]) -> dict[str, list[float]]:
    """Per ``name``, the mean of each finished run's ``row[entry][name]`` (its evaluation
    episodes): one number per finished seed, in ``rows``' order."""
    done = [row for row in rows if row["finished"]]
    return {name: [float(np.mean(row[entry][name])) for row in done] for name in names}
