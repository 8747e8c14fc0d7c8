"""The pose history: a fixed ring (memory allocated at start), bisected lookups, oldest dropped first."""

from __future__ import annotations

import numpy as np
import pytest

from gprbot.fusion.pose_history import PoseHistory
from gprbot.messages import Pose


def poses(times: np.ndarray) -> list[Pose]:
    return [Pose(float(t), np.array([t, 2 * t, 0.0]), np.array([0.0, 0.0, np.sin(t), np.cos(t)]), 0.01 * t, 0.1)
            for t in times]


@pytest.mark.parametrize("n", [0, 1, 5, 7, 8, 23])  # empty, partly full, exactly full, wrapped
def test_the_ring_keeps_the_newest_in_order_and_finds_them(n: int) -> None:
    history = PoseHistory(8)
    stamps = np.arange(n) * 0.5
    for chunk in np.array_split(stamps, 3):
        history.extend(poses(chunk))
    kept = stamps[-8:]
    assert len(history) == kept.size
    assert [p.t for p in history] == list(kept)
    newest = history.newest()
    if not n:
        assert newest is None and np.isnan(history.span()[0])
        assert history.between(-1.0, 100.0) == [] and history.around(-1.0, 100.0) == []
        return
    assert newest is not None and newest.t == kept[-1]
    assert newest.position == pytest.approx([kept[-1], 2 * kept[-1], 0.0])
    assert newest.position_std_m == pytest.approx(0.01 * kept[-1])
    assert history.span() == (kept[0], kept[-1])
    for t0, t1 in [(-1.0, 100.0), (kept[0], kept[0]), (kept[0] + 0.2, kept[-1] - 0.2), (kept[-1], 200.0)]:
        assert [p.t for p in history.between(t0, t1)] == [t for t in kept if t0 <= t <= t1]
        inside = np.flatnonzero((kept >= t0) & (kept <= t1))
        lo = max(int(np.searchsorted(kept, t0, side="right")) - 1, 0)
        hi = min(int(np.searchsorted(kept, t1, side="left")) + 1, kept.size)
        assert [p.t for p in history.around(t0, t1)] == list(kept[lo:hi])
        assert set(kept[inside]) <= {p.t for p in history.around(t0, t1)}


def test_the_memory_is_taken_at_start() -> None:
    history = PoseHistory(90_000)  # the daemon's 900 s at 100 Hz
    assert history._rows.nbytes == 90_000 * 10 * 8  # 7.2 MB, written (resident) now, not as it fills
    before = history._rows.__array_interface__["data"][0]
    history.extend(poses(np.arange(100_000) * 0.01))
    assert history._rows.__array_interface__["data"][0] == before and len(history) == 90_000
