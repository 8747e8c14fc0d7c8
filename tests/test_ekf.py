"""The loosely coupled filter: convergence, gyro bias, time ordering, VO dropouts, output and config."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gprbot.config import FusionConfig, MotorsConfig
from gprbot.errors import ConfigError, GprbotError
from gprbot.fusion.baselines import wheel_only
from gprbot.fusion.fuser import PoseFuser, SensorMessage
from gprbot.fusion.so3 import exp_so3, matrix_to_quat, yaw_of
from gprbot.messages import Pose, VoMeasurement, WheelSpeeds
from gprbot.sim.encoders import simulate_encoders
from gprbot.sim.imu import simulate_imu
from gprbot.sim.motion_truth import GroundTruth, straight_ground_truth

GYRO_BIAS = np.array([0.003, -0.002, 0.004])  # rad/s, ~0.2 °/s: a D435i after calibration


def synthetic_vo(truth: GroundTruth, seed: int, period_s: float = 0.5, gap: tuple[float, float] | None = None,
                 std_m: float = 1e-4, std_rad: float = 5e-5) -> list[VoMeasurement]:
    """Keyframe-relative VO from the truth with noise; no measurement inside `gap` (tracking lost)."""
    rng = np.random.default_rng(seed)
    times = np.arange(0.5, truth.t_end - 0.1, period_s)
    if gap is not None:
        times = times[(times < gap[0]) | (times > gap[1])]
    P, R = truth.position(times), truth.rotation(times)
    out = [VoMeasurement(float(times[0]), float(times[0]), "keyframe", new_keyframe=True)]
    covariance = np.diag([std_m**2] * 3 + [std_rad**2] * 3)
    for i in range(1, times.size):
        if gap is not None and times[i - 1] < gap[0] < times[i]:
            out.append(VoMeasurement(float(times[i]), float(times[i]), "keyframe", new_keyframe=True))
            continue
        step = R[i - 1].T @ (P[i] - P[i - 1]) + rng.normal(0.0, std_m, 3)
        turn = R[i - 1].T @ R[i] @ exp_so3(rng.normal(0.0, std_rad, 3))
        out.append(VoMeasurement(float(times[i]), float(times[i - 1]), "ok", matrix_to_quat(turn), step, covariance,
                                 100, True))
    return out


def sensor_messages(truth: GroundTruth, gap: tuple[float, float] | None = None) -> list[SensorMessage]:
    imu = simulate_imu(truth, seed=1, gyro_bias=GYRO_BIAS)
    wheels = simulate_encoders(truth, seed=1)
    messages: list[SensorMessage] = [*imu.messages(), *wheels.messages(), *synthetic_vo(truth, 2, gap=gap)]
    return sorted(messages, key=lambda m: m.t)


def start_of(truth: GroundTruth) -> tuple[tuple[float, float, float], float]:
    t0 = np.array([truth.t_start])
    p = truth.position(t0)[0]
    return (float(p[0]), float(p[1]), float(p[2])), yaw_of(truth.rotation(t0)[0])


def run(fuser: PoseFuser, messages: list[SensorMessage]) -> list[Pose]:
    poses = [pose for m in messages for pose in fuser.push(m)]
    return poses + fuser.flush()


def position_errors(poses: list[Pose], truth: GroundTruth) -> tuple[np.ndarray, np.ndarray]:
    t = np.array([p.t for p in poses])
    return t, np.linalg.norm(np.stack([p.position for p in poses]) - truth.position(t), axis=1)


@pytest.fixture(scope="module")
def straight() -> GroundTruth:
    return straight_ground_truth(25.0, (0.1, 0.0), seed=5)


def test_constant_velocity_run_converges_and_estimates_the_gyro_bias(straight: GroundTruth) -> None:
    config = FusionConfig(gyro_bias_from_rest=False, initial_gyro_bias_std_rad_s=0.01)
    position, yaw = start_of(straight)
    fuser = PoseFuser(config, initial_position=position, initial_yaw_rad=yaw)
    poses = run(fuser, sensor_messages(straight))
    t, error = position_errors(poses, straight)
    assert error[t > 5.0].max() < 0.005
    assert error[-1] < 0.004
    # The filter started from zero bias; VO turns and gravity tell it the truth.
    assert fuser.ekf.gyro_bias == pytest.approx(GYRO_BIAS, abs=2e-4)
    assert abs(fuser.stats.vo_updates - 48) <= 1 and fuser.stats.wheel_rejected < 5
    assert straight.position(np.array([t[-1]]))[0, 0] > 2.0


def test_out_of_order_arrival_gives_the_in_order_result(straight: GroundTruth) -> None:
    messages = sensor_messages(straight)
    position, yaw = start_of(straight)
    in_order = run(PoseFuser(initial_position=position, initial_yaw_rad=yaw), messages)
    rng = np.random.default_rng(7)
    # VO results arrive 40-90 ms late, wheel speeds 0-30 ms late: the order the filter sees is shuffled.
    delay = {VoMeasurement: (0.04, 0.09), WheelSpeeds: (0.0, 0.03)}
    arrival = [m.t + rng.uniform(*delay.get(type(m), (0.0, 0.0))) for m in messages]
    shuffled = [messages[i] for i in np.argsort(arrival, kind="stable")]
    assert shuffled != messages
    fuser = PoseFuser(initial_position=position, initial_yaw_rad=yaw)
    out_of_order = run(fuser, shuffled)
    assert fuser.stats.late_dropped == 0
    assert len(out_of_order) == len(in_order)
    assert np.stack([p.position for p in out_of_order]) == pytest.approx(np.stack([p.position for p in in_order]),
                                                                          abs=1e-9)
    # Later than the window: dropped and counted, never applied to the past.
    late = [m for m in messages if isinstance(m, VoMeasurement)][10]
    too_late = [m for m in messages if m is not late] + [late]
    fuser = PoseFuser(initial_position=position, initial_yaw_rad=yaw)
    run(fuser, too_late)
    assert fuser.stats.late_dropped == 1


def test_vo_dropout_is_bridged_by_wheels_and_imu(straight: GroundTruth) -> None:
    gap = (8.0, 15.0)
    messages = sensor_messages(straight, gap=gap)
    position, yaw = start_of(straight)
    poses = run(PoseFuser(initial_position=position, initial_yaw_rad=yaw), messages)
    t, error = position_errors(poses, straight)
    assert np.all(np.isfinite(error))
    # Over the gap the filter may drift no more than wheel odometry does over the same stretch.
    wheels = [m for m in messages if isinstance(m, WheelSpeeds) and gap[0] <= m.t <= gap[1]]
    t0 = np.array([wheels[0].t - 0.01])
    start, start_yaw = straight.position(t0)[0], yaw_of(straight.rotation(t0)[0])
    wheel_end = wheel_only(wheels, MotorsConfig(), start, start_yaw)[-1]
    wheel_truth = straight.position(np.array([wheel_end.t - 0.01]))[0, :2]
    wheel_drift = float(np.linalg.norm(wheel_end.position[:2] - wheel_truth))
    in_gap = (t > gap[0]) & (t < gap[1])
    growth = error[in_gap].max() - error[np.searchsorted(t, gap[0])]
    assert growth <= max(wheel_drift, 0.002) + 0.001
    assert error[t > gap[1] + 2.0].max() < 0.006  # and VO pulls it back in
    assert error.max() < 0.01


def test_pose_output_rate_and_pose_at(straight: GroundTruth) -> None:
    config = FusionConfig(output_rate_hz=50.0)
    position, yaw = start_of(straight)
    fuser = PoseFuser(config, initial_position=position, initial_yaw_rad=yaw)
    poses = run(fuser, sensor_messages(straight)[:8000])
    assert np.diff([p.t for p in poses]) == pytest.approx(np.full(len(poses) - 1, 0.02))
    middle = 0.5 * (poses[100].t + poses[101].t)
    between = fuser.pose_at(middle)[0]
    assert between.position == pytest.approx(0.5 * (poses[100].position + poses[101].position))
    with pytest.raises(GprbotError, match="poses cover"):
        fuser.pose_at(poses[-1].t + 1.0)
    assert math.isfinite(fuser.yaw_rad)


def test_fusion_config_rejects_nonsense() -> None:
    with pytest.raises(ConfigError, match=r"fusion\.gate_probability"):
        FusionConfig(gate_probability=1.5)
    with pytest.raises(ConfigError, match=r"fusion\.wheel_slip_std"):
        FusionConfig(wheel_slip_std=-0.1)
