"""Pose interpolation at any timestamp: linear in position, SLERP in orientation."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from gprbot.errors import GprbotError
from gprbot.messages import Pose


def interpolate_poses(poses: Sequence[Pose], t: NDArray[np.float64]) -> list[Pose]:
    """Poses at times t from a time-ordered pose sequence.

    Times outside the sequence are an error, not an extrapolation: a trace recorded before the
    first or after the last pose has no trustworthy position.
    """
    if len(poses) < 2:
        raise GprbotError("pose interpolation needs at least two poses; is the pose estimator running?")
    times = np.array([p.t for p in poses])
    if np.any(np.diff(times) <= 0):
        raise GprbotError("pose timestamps must be strictly increasing")
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    if t.size and (t.min() < times[0] - 1e-9 or t.max() > times[-1] + 1e-9):
        raise GprbotError(
            f"cannot tag data at t=[{t.min():.3f}, {t.max():.3f}] s: poses cover "
            f"[{times[0]:.3f}, {times[-1]:.3f}] s only"
        )
    t = np.clip(t, times[0], times[-1])
    positions = np.stack([p.position for p in poses])
    pos = np.stack([np.interp(t, times, positions[:, k]) for k in range(3)], axis=1)
    slerp = Slerp(times, Rotation.from_quat(np.stack([p.orientation for p in poses])))
    quats = slerp(t).as_quat()
    position_std = np.interp(t, times, [p.position_std_m for p in poses])
    yaw_std = np.interp(t, times, [p.yaw_std_rad for p in poses])
    return [Pose(float(ti), pos[i], quats[i], float(position_std[i]), float(yaw_std[i])) for i, ti in enumerate(t)]
