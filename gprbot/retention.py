"""Retention of old runs on the robot: keep the newest `max_runs` and at most `max_total_gb` in runs_dir.

Only directories holding a run log (log-000.msgpack with a readable header) count as runs; anything
else in runs_dir is never touched. Runs are ordered by the header's creation time (not by mtime, which
a pull or a replay into RUN/replay changes). The run being started and the protected names are kept
even when they alone exceed the limits.
"""

from __future__ import annotations

import logging
import shutil
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

from gprbot.config import RetentionConfig
from gprbot.errors import DataFormatError
from gprbot.runlog import segment_path
from gprbot.runlog_reader import RunLogReader

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StoredRun:
    """A run directory in runs_dir: its name, creation time (wall, s) and size on disk (bytes)."""

    name: str
    created: float
    size_bytes: int


def stored_runs(runs_dir: Path) -> list[StoredRun]:
    """The runs in runs_dir, oldest first (directories without a readable run log are not runs)."""
    found = []
    try:
        candidates = [p for p in Path(runs_dir).iterdir() if p.is_dir() and not p.is_symlink()]
    except FileNotFoundError:
        return []
    for path in candidates:
        if not segment_path(path, 0).is_file():
            continue
        try:
            created = float(RunLogReader(path).header.get("created") or 0.0)
        except DataFormatError:
            continue  # not ours to judge: leave it
        size = sum(f.stat().st_size for f in path.rglob("*") if f.is_file() and not f.is_symlink())
        found.append(StoredRun(path.name, created, size))
    return sorted(found, key=lambda r: (r.created, r.name))


def runs_to_delete(runs: list[StoredRun], policy: RetentionConfig, keep: Collection[str] = ()) -> list[StoredRun]:
    """The oldest runs to delete so that at most max_runs remain and their total is within max_total_gb."""
    remaining = list(runs)
    doomed: list[StoredRun] = []
    limit_bytes = None if policy.max_total_gb is None else policy.max_total_gb * 1e9

    def over() -> bool:
        too_many = policy.max_runs is not None and len(remaining) > policy.max_runs
        too_big = limit_bytes is not None and sum(r.size_bytes for r in remaining) > limit_bytes
        return too_many or too_big

    for run in list(remaining):
        if not over():
            break
        if run.name in keep:
            continue
        remaining.remove(run)
        doomed.append(run)
    return doomed


def prune_runs(runs_dir: Path, policy: RetentionConfig, keep: Collection[str] = ()) -> list[StoredRun]:
    """Delete the oldest runs beyond the policy's limits (never those in keep); returns what was deleted."""
    if policy.max_runs is None and policy.max_total_gb is None:
        return []
    doomed = runs_to_delete(stored_runs(runs_dir), policy, keep)
    for run in doomed:
        log.info("retention: deleting run %s (%.1f MB)", run.name, run.size_bytes / 1e6)
        shutil.rmtree(Path(runs_dir) / run.name, ignore_errors=True)
    return doomed
