"""Simulated sensors: IMU noise statistics, IMU consistency with the motion, encoders, rendered depth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gprbot.config import MotorsConfig
from gprbot.fusion.baselines import imu_dead_reckoning, wheel_only
from gprbot.fusion.so3 import log_so3, quat_to_matrix, yaw_of
from gprbot.geometry import CameraMount
from gprbot.sim.camera import CameraModel, FloorCamera
from gprbot.sim.encoders import simulate_encoders
from gprbot.sim.floor_texture import FloorSpec
from gprbot.sim.imu import ImuModel, allan_deviation, simulate_imu
from gprbot.sim.motion_truth import GRAVITY_M_S2, jog_ground_truth, straight_ground_truth

QUIET = {"gyro_turn_on_bias_std": 0.0, "accel_turn_on_bias_std": 0.0, "gyro_lsb": 0.0, "accel_lsb": 0.0}


def _mean_adev(samples: np.ndarray, rate_hz: float, taus: np.ndarray) -> np.ndarray:
    return np.mean([allan_deviation(samples[:, axis], rate_hz, taus) for axis in range(3)], axis=0)


def test_static_imu_white_noise_matches_configured_density() -> None:
    model = ImuModel(gyro_bias_walk=0.0, accel_bias_walk=0.0, **QUIET)
    rec = simulate_imu(straight_ground_truth(100.0, (0.0, 0.0), rough=False), model, seed=3)
    taus = np.array([0.05, 0.5])
    # White noise of density N has Allan deviation N/√τ (IEEE Std 952); an error in the √rate
    # scaling of the discrete noise would be off by a factor of 20.
    gyro = _mean_adev(rec.gyro, model.gyro_rate_hz, taus) / (model.gyro_noise_density / np.sqrt(taus))
    accel = _mean_adev(rec.accel, model.accel_rate_hz, taus) / (model.accel_noise_density / np.sqrt(taus))
    assert gyro == pytest.approx([1.0, 1.0], abs=0.08)
    assert accel == pytest.approx([1.0, 1.0], abs=0.08)
    assert rec.accel.mean(axis=0) == pytest.approx([0.0, 0.0, GRAVITY_M_S2], abs=1e-3)
    assert np.diff(rec.gyro_t) == pytest.approx(np.full(rec.gyro_t.size - 1, 1 / 400))
    assert np.diff(rec.accel_t) == pytest.approx(np.full(rec.accel_t.size - 1, 1 / 250))


def test_static_imu_bias_walk_matches_configured_random_walk() -> None:
    walk = 1e-3
    model = ImuModel(gyro_rate_hz=100.0, accel_rate_hz=100.0, gyro_noise_density=0.0, accel_noise_density=0.0,
                     gyro_bias_walk=walk, accel_bias_walk=walk, **QUIET)
    rec = simulate_imu(straight_ground_truth(300.0, (0.0, 0.0), rough=False), model, seed=1)
    tau = np.array([5.0])
    expected = walk * np.sqrt(tau / 3.0)  # rate random walk K: σ(τ) = K √(τ/3)
    assert _mean_adev(rec.gyro, 100.0, tau) / expected == pytest.approx([1.0], abs=0.25)
    assert _mean_adev(rec.accel, 100.0, tau) / expected == pytest.approx([1.0], abs=0.25)


def test_noise_free_imu_integrates_to_the_true_motion() -> None:
    """Angular rate and specific force are consistent with the poses (bumps, tilt, yaw wobble included)."""
    truth = jog_ground_truth(20.0, seed=4)
    model = ImuModel(gyro_noise_density=0.0, accel_noise_density=0.0, gyro_bias_walk=0.0, accel_bias_walk=0.0, **QUIET)
    rec = simulate_imu(truth, model)
    t0 = np.array([0.0])
    poses = imu_dead_reckoning(rec.messages(), truth.position(t0)[0], yaw_of(truth.rotation(t0)[0]), 0.5)
    end = poses[-1]
    assert np.linalg.norm(end.position - truth.position(np.array([end.t]))[0]) < 0.005
    true_R = truth.rotation(np.array([end.t]))[0]
    assert math.degrees(np.linalg.norm(log_so3(true_R.T @ quat_to_matrix(end.orientation)))) < 0.01
    travelled = truth.position(np.arange(0.0, 20.0, 0.1))
    assert np.max(np.linalg.norm(travelled[:, :2] - travelled[0, :2], axis=1)) > 0.3  # it did go somewhere


def test_encoders_give_wheel_odometry_of_the_truth_and_err_with_slip() -> None:
    truth = straight_ground_truth(20.0, (0.15, 0.1), seed=2)
    motors = MotorsConfig()
    t0 = np.array([0.0])
    start, yaw = truth.position(t0)[0], yaw_of(truth.rotation(t0)[0])

    def final_error(ideal: bool) -> float:
        rec = simulate_encoders(truth, motors, seed=5, ideal=ideal)
        assert np.diff(rec.t) == pytest.approx(np.full(rec.t.size - 1, 0.02))
        end = wheel_only(rec.messages(), motors, start, yaw)[-1]
        # Each speed is the mean over a 20 ms poll: integrated, they describe the pose half a poll ago.
        return float(np.linalg.norm(end.position[:2] - truth.position(np.array([end.t - 0.01]))[0, :2]))

    ideal = final_error(ideal=True)
    assert ideal < 0.005  # count quantisation only (one count of heading ≈ 0.04° over 3.4 m)
    assert final_error(ideal=False) > max(0.01, 3 * ideal)  # ±1.5 % radii and slip
    scale = simulate_encoders(truth, motors, seed=5).radius_scale
    assert np.all(np.abs(scale - 1.0) <= 0.015) and np.any(scale != 1.0)


def test_rendered_depth_follows_the_floor_geometry() -> None:
    mount = CameraMount(position_m=(0.2, 0.0, 0.3), pitch_down_deg=60.0)
    camera = FloorCamera(FloorSpec(size_px=(512, 512), smooth_patches_m=()), CameraModel(mount=mount), seed=1)
    frame = camera.render(0.0, np.eye(3), np.zeros(3))
    k = frame.intrinsics
    assert frame.color.shape == (240, 424, 3) and frame.color.dtype == np.uint8
    assert frame.depth_m.dtype == np.float32
    column = round(k.cx)
    for row in (10, 60, 120, 180, 230):
        # The pixel's ray dips below the optical axis by δ: it meets the floor at range h / sin(60° + δ),
        # and depth is that range along the optical axis, × cos δ.
        below = math.atan((row - k.cy) / k.fy)
        expected = 0.3 / math.sin(math.radians(60.0) + below) * math.cos(below)
        patch = frame.depth_m[row - 2:row + 3, column - 2:column + 3]
        assert float(np.median(patch[patch > 0])) == pytest.approx(expected, abs=0.002)
    assert 0.0 < float(np.mean(frame.depth_m == 0.0)) < 0.02  # a few holes


def test_texture_poor_patch_has_no_contrast() -> None:
    spec = FloorSpec(size_px=(1024, 1024), origin_m=(0.0, 0.0), smooth_patches_m=((0.3, 0.3, 0.7, 0.7),))
    camera = FloorCamera(spec, seed=2)
    gray = camera.floor.image.astype(float)
    assert gray[400:600, 400:600].std() < 3.0  # inside the patch (tile pixels are mm)
    assert gray[50:250, 50:250].std() > 20.0
