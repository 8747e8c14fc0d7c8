"""The filter's recent output poses in arrays allocated once, so the daemon's memory does not grow.

A deque of `Pose` objects (two small arrays each, ~400 bytes) grew the daemon by ~35 MiB while its
900 s at 100 Hz filled, and every lookup walked it in Python. Here the poses of the last `capacity`
ticks live in a ring of float64 rows (80 bytes a pose, written at start so the pages are resident);
lookups bisect the time column.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np
from numpy.typing import NDArray

from gprbot.messages import Pose

# one row: t, position (3), orientation (x, y, z, w), position_std_m, yaw_std_rad
_T, _POS, _QUAT, _POS_STD, _YAW_STD = 0, slice(1, 4), slice(4, 8), 8, 9
_WIDTH = 10


class PoseHistory:
    """The newest `capacity` poses, oldest first; appends must come in increasing time."""

    def __init__(self, capacity: int) -> None:
        self.capacity = max(2, capacity)
        self._rows = np.full((self.capacity, _WIDTH), np.nan)  # full, not zeros: resident now, not as it fills
        self._start = 0
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def __iter__(self) -> Iterator[Pose]:
        return iter(self._poses(0, self._count))

    def extend(self, poses: Iterable[Pose]) -> None:
        """Append poses (each later than the newest kept), dropping the oldest beyond the capacity."""
        for pose in poses:
            end = (self._start + self._count) % self.capacity
            row = self._rows[end]
            row[_T], row[_POS], row[_QUAT] = pose.t, pose.position, pose.orientation
            row[_POS_STD], row[_YAW_STD] = pose.position_std_m, pose.yaw_std_rad
            if self._count < self.capacity:
                self._count += 1
            else:
                self._start = (self._start + 1) % self.capacity

    def newest(self) -> Pose | None:
        """The most recent pose, if any."""
        return self._poses(self._count - 1, self._count)[0] if self._count else None

    def span(self) -> tuple[float, float]:
        """The times of the oldest and the newest pose kept (NaN when empty)."""
        if not self._count:
            return float("nan"), float("nan")
        first, second = self._times()
        return float(first[0]), float(second[-1] if second.size else first[-1])

    def between(self, t0: float, t1: float) -> list[Pose]:
        """The poses with t0 <= t <= t1."""
        return self._poses(self._index(t0, "left"), self._index(t1, "right"))

    def around(self, t0: float, t1: float) -> list[Pose]:
        """The poses covering [t0, t1]: those inside plus one on either side where there is one."""
        return self._poses(max(self._index(t0, "right") - 1, 0), min(self._index(t1, "left") + 1, self._count))

    def _times(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The time column as its two contiguous pieces, in order (the second is empty until it wraps)."""
        end = self._start + self._count
        if end <= self.capacity:
            return self._rows[self._start:end, _T], self._rows[:0, _T]
        return self._rows[self._start:, _T], self._rows[:end - self.capacity, _T]

    def _index(self, t: float, side: str) -> int:
        """The logical index at which t would be inserted (numpy's searchsorted `side`)."""
        first, second = self._times()
        index = int(np.searchsorted(first, t, side=side))  # type: ignore[call-overload]
        if index < first.size:
            return index
        return first.size + int(np.searchsorted(second, t, side=side))  # type: ignore[call-overload]

    def _poses(self, lo: int, hi: int) -> list[Pose]:
        """Poses at logical indices [lo, hi)."""
        if hi <= lo:
            return []
        rows = self._rows[(self._start + np.arange(lo, hi)) % self.capacity]
        return [Pose(float(r[_T]), r[_POS].copy(), r[_QUAT].copy(), float(r[_POS_STD]), float(r[_YAW_STD]))
                for r in rows]
