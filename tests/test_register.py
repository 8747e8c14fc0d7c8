"""Registration of cross-section masks in 3D: antenna positions, pixel mapping, resampling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gprbot.errors import InterpretationError
from gprbot.geometry import antenna_positions
from gprbot.messages import Pose
from gprbot.reconstruct.register import register_slice, resample_cloud


def yaw_quaternion(deg: float) -> np.ndarray:
    half = math.radians(deg) / 2
    return np.array([0.0, 0.0, math.sin(half), math.cos(half)])


def test_antenna_position_of_a_yawed_pose_rotates_the_lever_arm() -> None:
    poses = [
        Pose(0.0, np.array([1.0, 2.0, 0.1]), yaw_quaternion(90.0)),
        Pose(0.1, np.array([1.0, 2.0, 0.1]), yaw_quaternion(30.0)),
        Pose(0.2, np.array([-1.0, 0.5, 0.0])),
    ]
    got = antenna_positions(poses, (0.25, 0.0, 0.05))
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    expected = [[1.0, 2.25, 0.15], [1.0 + 0.25 * c, 2.0 + 0.25 * s, 0.15], [-0.75, 0.5, 0.05]]
    np.testing.assert_allclose(got, expected, atol=1e-12)


def test_antenna_position_of_a_tilted_pose() -> None:
    tilt = math.radians(1.0)  # pitch about y: the arm's tip dips by L·sin θ
    quat = np.array([0.0, math.sin(tilt / 2), 0.0, math.cos(tilt / 2)])
    got = antenna_positions([Pose(0.0, np.zeros(3), quat)], (0.25, 0.0, 0.0))
    np.testing.assert_allclose(got, [[0.25 * math.cos(tilt), 0.0, -0.25 * math.sin(tilt)]], atol=1e-12)


def test_antenna_positions_of_no_poses_and_bad_quaternions() -> None:
    assert antenna_positions([], (0.25, 0.0, 0.0)).shape == (0, 3)
    with pytest.raises(InterpretationError, match="quaternion"):
        antenna_positions([Pose(0.0, np.zeros(3), np.zeros(4))], (0.25, 0.0, 0.0))


def test_register_slice_maps_pixels_by_hand() -> None:
    mask = np.zeros((3, 4), dtype=bool)
    mask[0, 1] = mask[1, 0] = mask[2, 3] = True
    z_m = np.array([0.1, 0.2, 0.3])
    columns = np.array([[1.0, 2.0, 0.02], [1.1, 2.0, 0.02], [1.2, 2.01, 0.02], [1.3, 2.02, 0.02]])
    cloud = register_slice(7, mask, z_m, columns)
    assert cloud.line == 7
    # Row-major pixel order: (0, 1), (1, 0), (2, 3); the antenna's own height does not enter the depth.
    np.testing.assert_allclose(cloud.points, [[1.1, 2.0, -0.1], [1.0, 2.0, -0.2], [1.3, 2.02, -0.3]])
    assert cloud.direction[0] > 0.99 and abs(np.linalg.norm(cloud.direction) - 1.0) < 1e-12
    assert cloud.pixel_pitch_m == pytest.approx((0.1, 0.1), abs=1e-3)


def test_register_slice_direction_follows_the_driving_direction() -> None:
    columns = np.column_stack([np.linspace(2.0, 0.0, 5), np.full(5, 0.3), np.zeros(5)])
    cloud = register_slice(1, np.zeros((2, 5), dtype=bool), np.array([0.0, 0.01]), columns)
    np.testing.assert_allclose(cloud.direction, [-1.0, 0.0], atol=1e-12)
    assert cloud.points.shape == (0, 3)


def test_register_slice_rejects_mismatched_shapes_and_a_standing_line() -> None:
    with pytest.raises(InterpretationError, match="column positions"):
        register_slice(0, np.zeros((3, 4), dtype=bool), np.zeros(3), np.zeros((5, 3)))
    with pytest.raises(InterpretationError, match="along-track"):
        register_slice(0, np.zeros((3, 4), dtype=bool), np.arange(3.0), np.ones((4, 3)))


def test_resample_subset_keeps_distinct_input_points() -> None:
    rng = np.random.default_rng(0)
    points = rng.normal(size=(500, 3))
    out = resample_cloud(points, 100, rng)
    assert out.shape == (100, 3)
    rows = {tuple(p) for p in points}
    assert all(tuple(p) in rows for p in out)
    assert len({tuple(p) for p in out}) == 100


def test_resample_upsamples_with_jittered_repeats() -> None:
    rng = np.random.default_rng(1)
    points = rng.uniform(size=(40, 3))
    out = resample_cloud(points, 100, rng)
    assert out.shape == (100, 3)
    nearest = np.min(np.linalg.norm(out[:, None, :] - points[None, :, :], axis=2), axis=1)
    assert np.count_nonzero(nearest == 0.0) == 40  # every original exactly once
    assert np.all(nearest < 2e-3)
    assert len({tuple(p) for p in out}) == 100  # no coincident duplicates


def test_farthest_point_resampling_spreads_over_the_shape() -> None:
    rng = np.random.default_rng(2)
    dense_end = rng.normal(scale=0.01, size=(900, 3))
    sparse_end = np.array([[1.0, 0.0, 0.0]]) + rng.normal(scale=0.01, size=(100, 3))
    points = np.vstack([dense_end, sparse_end])
    out = resample_cloud(points, 20, rng, method="farthest")
    assert np.count_nonzero(out[:, 0] > 0.5) >= 5  # uniform would give ~2 of 20


def test_resample_of_an_empty_cloud_says_what_to_check() -> None:
    with pytest.raises(InterpretationError, match="empty point cloud"):
        resample_cloud(np.zeros((0, 3)), 10, np.random.default_rng(0))
