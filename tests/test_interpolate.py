"""Pose interpolation: linear position, SLERP orientation, refusal to extrapolate."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gprbot.errors import GprbotError
from gprbot.fusion.interpolate import interpolate_poses
from gprbot.messages import Pose


def _pose(t: float, x: float, yaw_deg: float) -> Pose:
    return Pose(t, np.array([x, 0.0, 0.0]), Rotation.from_euler("z", yaw_deg, degrees=True).as_quat())


def test_linear_position_and_slerp_yaw() -> None:
    poses = [_pose(0.0, 0.0, 0.0), _pose(2.0, 1.0, 10.0)]
    out = interpolate_poses(poses, np.array([0.5, 1.0, 2.0]))
    assert [p.position[0] for p in out] == pytest.approx([0.25, 0.5, 1.0])
    yaws = [Rotation.from_quat(p.orientation).as_euler("xyz", degrees=True)[2] for p in out]
    assert yaws == pytest.approx([2.5, 5.0, 10.0], abs=1e-9)


def test_no_extrapolation_and_ordered_times() -> None:
    poses = [_pose(0.0, 0.0, 0.0), _pose(1.0, 1.0, 0.0)]
    with pytest.raises(GprbotError, match="poses cover"):
        interpolate_poses(poses, np.array([1.5]))
    with pytest.raises(GprbotError, match="strictly increasing"):
        interpolate_poses([poses[1], poses[0]], np.array([0.5]))
    with pytest.raises(GprbotError, match="at least two"):
        interpolate_poses(poses[:1], np.array([0.0]))
