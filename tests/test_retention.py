"""Retention of old runs: the newest max_runs and at most max_total_gb stay; nothing but run logs is touched."""

from __future__ import annotations

from pathlib import Path

import pytest

from gprbot.config import ConfigError, RetentionConfig, load_config
from gprbot.retention import prune_runs, stored_runs
from gprbot.runlog import RunLogWriter, make_run_header


def _run(runs: Path, name: str, created: float, payload_bytes: int = 0) -> None:
    writer = RunLogWriter(runs / name, make_run_header(load_config(), created))
    writer.close({})
    if payload_bytes:
        (runs / name / "dense.ply").write_bytes(b"\0" * payload_bytes)


def test_the_oldest_runs_go_first_and_others_stay(tmp_path: Path) -> None:
    # names sort differently from creation times on purpose: the header's time decides
    for index, name in enumerate(["c-run", "a-run", "d-run", "b-run"]):
        _run(tmp_path, name, 1000.0 + index)
    (tmp_path / "notes").mkdir()  # not a run: never deleted
    (tmp_path / "torn").mkdir()
    (tmp_path / "torn" / "log-000.msgpack").write_bytes(b"garbage")  # unreadable header: left alone
    deleted = prune_runs(tmp_path, RetentionConfig(max_runs=2), keep={"c-run"})
    # c-run is the oldest but protected (the run being started); then the newest: b-run
    assert [r.name for r in deleted] == ["a-run", "d-run"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b-run", "c-run", "notes", "torn"]


def test_a_size_limit_deletes_until_the_rest_fits(tmp_path: Path) -> None:
    for index in range(4):
        _run(tmp_path, f"run{index}", 2000.0 + index, payload_bytes=400_000)
    deleted = prune_runs(tmp_path, RetentionConfig(max_total_gb=0.001))  # 1 MB: two runs of ~0.4 MB fit
    assert [r.name for r in deleted] == ["run0", "run1"]
    assert [r.name for r in stored_runs(tmp_path)] == ["run2", "run3"]


def test_no_limit_keeps_everything_and_bad_limits_are_refused(tmp_path: Path) -> None:
    _run(tmp_path, "only", 1.0)
    assert prune_runs(tmp_path, RetentionConfig()) == []
    with pytest.raises(ConfigError, match=r"retention\.max_runs"):
        RetentionConfig(max_runs=0)
    with pytest.raises(ConfigError, match=r"retention\.max_total_gb"):
        RetentionConfig(max_total_gb=-1.0)
