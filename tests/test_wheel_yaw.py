"""The wheels must not pull the fused yaw away from the gyro when the true wheel radii differ (issue 14).

Commanded wheel speeds without rotation turn a base whose wheels are not all the same size: the gyro
sees the turn, the encoders cannot. The filter used to fuse the rims' common mode as a turn rate and
pulled the yaw back towards "no turn" (gyro 0.01 rad/s for 5 s, wheels 0: fused yaw 0.029, not 0.050).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gprbot.config import FusionConfig, MotorsConfig
from gprbot.fusion.fuser import PoseFuser, SensorMessage
from gprbot.messages import ImuSample, WheelSpeeds
from gprbot.motion.kinematics import kiwi_matrix
from gprbot.sim.imu import ImuModel
from gprbot.simulated.robot import WHEEL_RADIUS_ERROR

GYRO_BIAS = np.array([0.003, -0.002, 0.004])  # rad/s: a D435i's turn-on bias, removed by the at-rest mean
REST_S = 10.0
GYRO_SAMPLE_STD = ImuModel().gyro_noise_density * math.sqrt(ImuModel().gyro_rate_hz)
# The at-rest mean of N gyro samples leaves a bias error of std σ/√N, which grows into yaw over the drive.
REST_BIAS_STD = GYRO_SAMPLE_STD / math.sqrt(REST_S * ImuModel().gyro_rate_hz)


def drive(radius_error: tuple[float, float, float], speed_m_s: float, drive_s: float, *, wheels_still: bool = False,
          extra_turn_rad_s: float = 0.0, seed: int = 0) -> tuple[float, list[SensorMessage]]:
    """At rest, then the wheels commanded to drive straight along x; the true final yaw and the sensors."""
    motors = MotorsConfig()
    K = kiwi_matrix(motors.base_radius_m)
    rng = np.random.default_rng(seed)
    dt = 1e-3
    t = np.arange(0.0, REST_S + drive_s, dt)
    moving = t > REST_S
    v = speed_m_s * np.clip((t - REST_S) / 0.5, 0.0, 1.0)
    commanded_rims = np.column_stack([v, 0 * v, 0 * v]) @ K.T
    twist = (commanded_rims * (1.0 + np.asarray(radius_error))) @ np.linalg.inv(K).T  # the wheels' true radii
    twist[:, 2] += extra_turn_rad_s * moving
    yaw = np.concatenate([[0.0], np.cumsum(twist[1:, 2] * dt)])
    body_accel = np.gradient(twist[:, :2], dt, axis=0)
    body_accel += np.column_stack([-twist[:, 2] * twist[:, 1], twist[:, 2] * twist[:, 0]])  # ω × v
    accel_std = ImuModel().accel_noise_density * math.sqrt(ImuModel().accel_rate_hz)
    messages: list[SensorMessage] = []
    for i in range(0, t.size, 2):  # 500 Hz, near enough the D435i's 400 Hz gyro for this
        gyro = np.array([0.0, 0.0, twist[i, 2]]) + GYRO_BIAS + rng.normal(0.0, GYRO_SAMPLE_STD, 3)
        messages.append(ImuSample(float(t[i]), gyro=gyro))
    for i in range(0, t.size, 4):
        accel = np.array([body_accel[i, 0], body_accel[i, 1], 9.80665]) + rng.normal(0.0, accel_std, 3)
        messages.append(ImuSample(float(t[i]), accel=accel))
    for i in range(20, t.size, 20):
        speeds = np.zeros(3) if wheels_still else commanded_rims[i] / motors.wheel_radius_m
        messages.append(WheelSpeeds(float(t[i]), speeds))
    messages.sort(key=lambda m: m.t)
    return float(yaw[-1]), messages


def fused_yaw(messages: list[SensorMessage]) -> float:
    fuser = PoseFuser(FusionConfig(init_duration_s=REST_S - 0.2), MotorsConfig())
    for message in messages:
        fuser.push(message)
    fuser.flush()
    return fuser.yaw_rad


def test_unequal_radii_turn_the_fused_yaw_as_the_gyro_sees_it() -> None:
    drive_s = 20.0  # 1 m at a slow survey speed: the rims then say little about the radii
    true_yaw, messages = drive(WHEEL_RADIUS_ERROR, 0.05, drive_s)
    assert abs(true_yaw) > 0.03  # the simulated robot's radii turn it by ~2° over 1 m
    # What is left is the at-rest bias estimate's own error (3σ) integrated over the drive.
    assert fused_yaw(messages) == pytest.approx(true_yaw, abs=3.0 * REST_BIAS_STD * drive_s)


def test_a_turn_the_wheels_do_not_report_is_not_pulled_back() -> None:
    drive_s = 5.0
    true_yaw, messages = drive((0.0, 0.0, 0.0), 0.0, drive_s, wheels_still=True, extra_turn_rad_s=0.01)
    assert true_yaw == pytest.approx(0.05, abs=1e-3)
    assert fused_yaw(messages) == pytest.approx(true_yaw, abs=3.0 * REST_BIAS_STD * drive_s)
