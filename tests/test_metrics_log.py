"""The run's metrics files survive a process killed mid-write."""

import json

import pytest

from iap_mjx.es.metrics_log import MetricsWriter, read_history


def rows(n):
    return [{"iteration": i, "return_mean": float(i)} for i in range(1, n + 1)]


def test_truncated_last_line_is_dropped_and_resume_rewrites_the_files(tmp_path):
    writer = MetricsWriter(tmp_path, 0, tensorboard=False)
    for row in rows(4):
        writer.write(row)
    writer.close()
    with open(tmp_path / "metrics.jsonl", "a") as f:
        f.write('{"iteration": 5, "retu')  # killed mid-write
    assert [r["iteration"] for r in read_history(tmp_path)] == [1, 2, 3, 4]
    resumed = MetricsWriter(tmp_path, 3, tensorboard=False)  # the checkpoint is at 3
    assert [r["iteration"] for r in resumed.kept] == [1, 2, 3]
    lines = (tmp_path / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(line)["iteration"] for line in lines] == [1, 2, 3]
    assert len((tmp_path / "metrics.csv").read_text().splitlines()) == 1 + 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metrics.csv", "metrics.jsonl"]


def test_a_damaged_line_before_the_last_is_an_error(tmp_path):
    (tmp_path / "metrics.jsonl").write_text('{"iteration": 1}\n{"iter\n{"iteration": 3}\n')
    with pytest.raises(ValueError, match="line 2"):
        read_history(tmp_path)


def test_an_envs_episode_statistics_get_their_columns_and_keep_them_on_resume(tmp_path):
    """``metric_columns``: two columns per statistic after ``contact_saturated_episodes``;
    a resumed writer with the same columns rewrites the header it had."""
    import csv

    from iap_mjx.es.metrics_log import COLUMNS, metric_columns

    columns = metric_columns(("walls_passed", "distance"))
    at = COLUMNS.index("contact_saturated_episodes") + 1
    assert columns[at : at + 4] == ("walls_passed_mean", "eval_walls_passed", "distance_mean", "eval_distance")
    assert tuple(c for c in columns if c not in columns[at : at + 4]) == COLUMNS and metric_columns() == COLUMNS
    writer = MetricsWriter(tmp_path, 0, tensorboard=False, columns=columns)
    for i in (1, 2):
        writer.write({"iteration": i, "walls_passed_mean": 0.5 * i, "eval_distance": 1.5})
    writer.close()
    MetricsWriter(tmp_path, 1, tensorboard=False, columns=columns).close()
    with open(tmp_path / "metrics.csv") as f:
        reader = csv.DictReader(f)
        stored = list(reader)
    assert tuple(reader.fieldnames) == columns
    assert [(r["walls_passed_mean"], r["eval_distance"]) for r in stored] == [("0.5", "1.5")]
