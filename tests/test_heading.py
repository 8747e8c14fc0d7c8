"""Heading hold: the PI loop's signs, limit and anti-windup, and yaw held on a simulated imbalanced robot."""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass, field

import numpy as np
import pytest

from gprbot.config import MotorsConfig
from gprbot.motion.heading import HeadingHold, HeadingHoldDrive, HeadingHoldGains
from gprbot.motion.kinematics import KiwiKinematics

MOTORS = MotorsConfig()
KIN = KiwiKinematics.from_config(MOTORS)
DEG = math.pi / 180.0
NO_HOLD = HeadingHoldGains(kp_per_s=0.0, ki_per_s2=0.0, kd_gyro=0.0)


def test_public_drive_api_has_no_rotation_argument() -> None:
    names = list(inspect.signature(HeadingHoldDrive.step).parameters)
    assert names == ["self", "vx", "vy", "yaw_rad", "gyro_z_rad_s", "dt_s", "t"]


def test_drive_produces_rotation_only_from_heading_error() -> None:
    drive = HeadingHoldDrive.from_config(MOTORS)
    on_target = drive.step(0.1, 0.05, yaw_rad=0.0, gyro_z_rad_s=0.0, dt_s=1.0, t=1.0)
    np.testing.assert_allclose(KIN.body_twist(on_target.speeds), [0.1, 0.05, 0.0], atol=1e-12)
    assert on_target.t == 1.0
    turned_left = drive.step(0.1, 0.05, yaw_rad=2 * DEG, gyro_z_rad_s=0.0, dt_s=1.0, t=2.0)
    omega = KIN.body_twist(turned_left.speeds)[2]
    gains = drive.hold.gains
    assert omega == pytest.approx(-2 * DEG * (gains.kp_per_s + gains.ki_per_s2 * 1.0), rel=1e-9)


def test_hold_output_is_clamped_and_damped_by_gyro() -> None:
    hold = HeadingHold(HeadingHoldGains(kp_per_s=1.5, ki_per_s2=0.0, kd_gyro=0.05, max_omega_rad_s=0.2))
    assert hold.update(-30 * DEG, 0.0, 0.01) == pytest.approx(0.2)  # far right of target: turn left, clamped
    assert hold.update(0.0, 0.1, 0.01) == pytest.approx(-0.005)  # turning left, on target: brake
    assert hold.update(math.pi - 0.01, 0.0, 0.01) == pytest.approx(-0.2)  # errors wrap into ±π


def test_integral_removes_steady_drift() -> None:
    """A constant disturbance rate is cancelled: the closed loop settles at zero yaw error."""
    hold = HeadingHold(HeadingHoldGains(kp_per_s=1.5, ki_per_s2=0.3, kd_gyro=0.05))
    yaw, disturbance, dt = 0.0, 0.01, 0.01
    for _ in range(6000):
        rate = hold.update(yaw, 0.0, dt) + disturbance
        yaw += rate * dt
    assert abs(yaw) < 1e-5
    assert hold.integral_rad_s == pytest.approx(-disturbance, rel=1e-3)


def test_anti_windup_keeps_the_integral_from_growing_while_saturated() -> None:
    gains = HeadingHoldGains(kp_per_s=1.5, ki_per_s2=0.3, kd_gyro=0.0, max_omega_rad_s=0.2)
    hold = HeadingHold(gains)
    for _ in range(6000):  # 60 s stuck 30° off (e.g. held by hand): output saturated throughout
        assert hold.update(-30 * DEG, 0.0, 0.01) == pytest.approx(0.2)
    # Unclamped, ki·∫e would be 0.3·0.52·60 ≈ 9.4 rad/s; conditional integration keeps it at zero.
    assert abs(hold.integral_rad_s) < 1e-12
    # Released on target, it does not keep turning on a wound-up integral.
    assert hold.update(0.0, 0.0, 0.01) == pytest.approx(0.0, abs=1e-12)
    assert hold.update(1 * DEG, 0.0, 0.01) < 0.0


# --- a simulated imbalanced kiwi robot -------------------------------------------------------------

GYRO_NOISE_DENSITY = 0.014 * DEG  # rad/s/√Hz (BMI055 datasheet: 0.014 °/s/√Hz)
GYRO_BIAS = 1.0 * DEG  # rad/s (BMI055 zero-rate offset, typical ±1 °/s)
YAW_NOISE = 0.1 * DEG  # rad, white, on the fused yaw
CONTROL_DT = 0.01  # 100 Hz control loop; gyro averaged over each period


def contact_geometry_matrix(d: float) -> np.ndarray:
    """Rim speeds from the twist, built from wheel positions and drive directions (not the paper's rows)."""
    rows = []
    for theta in (0.0, 2 * math.pi / 3, -2 * math.pi / 3):
        u = np.array([math.cos(theta), math.sin(theta)])
        p = d * np.array([-math.sin(theta), math.cos(theta)])
        rows.append([u[0], u[1], u @ np.array([-p[1], p[0]])])
    return np.array(rows)


@dataclass
class SimulatedKiwi:
    """Three omni wheels with unequal radii, a first-order motor lag and random slip; the true pose."""

    radius_scale: tuple[float, float, float] = (1.02, 0.98, 1.0)
    lag_s: float = 0.08
    slip_std: float = 0.02
    seed: int = 7
    pose: np.ndarray = field(default_factory=lambda: np.zeros(3))
    wheels: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rate: float = 0.0

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self.twist_from_rim = np.linalg.inv(contact_geometry_matrix(MOTORS.base_radius_m))
        self.radii = MOTORS.wheel_radius_m * np.array(self.radius_scale)

    def step(self, commanded: np.ndarray, dt: float) -> None:
        """Advance the true state by dt under commanded wheel speeds (Euler, 10 sub-steps)."""
        sub = dt / 10
        for _ in range(10):
            self.wheels += (commanded - self.wheels) * (1.0 - math.exp(-sub / self.lag_s))
            rim = self.radii * self.wheels * (1.0 + self.slip_std * self.rng.standard_normal(3))
            vx, vy, omega = self.twist_from_rim @ rim
            yaw = self.pose[2]
            self.pose += sub * np.array(
                [math.cos(yaw) * vx - math.sin(yaw) * vy, math.sin(yaw) * vx + math.cos(yaw) * vy, omega]
            )
            self.rate = omega

    def gyro_z(self) -> float:
        """A BMI055-like gyro z reading averaged over one control period."""
        sigma = GYRO_NOISE_DENSITY * math.sqrt(1.0 / (2.0 * CONTROL_DT))
        return self.rate + GYRO_BIAS + sigma * float(self.rng.standard_normal())

    def fused_yaw(self) -> float:
        """The filter's yaw estimate: the true yaw plus small white noise."""
        return float(self.pose[2]) + YAW_NOISE * float(self.rng.standard_normal())


def boustrophedon(
    lines: int = 10, length_m: float = 2.0, step_m: float = 0.1, speed: float = 0.1
) -> list[tuple[float, float, float]]:
    """(vx, vy, duration) legs: forward, sideways, backward, sideways, ..."""
    legs = []
    for line in range(lines):
        legs.append(((speed if line % 2 == 0 else -speed), 0.0, length_m / speed))
        if line < lines - 1:
            legs.append((0.0, speed, step_m / speed))
    return legs


def run_survey(gains: HeadingHoldGains) -> tuple[float, float]:
    """Max |true yaw| (degrees) over the survey and final lateral position (m) for the given gains."""
    robot = SimulatedKiwi()
    drive = HeadingHoldDrive.from_config(MOTORS, gains)
    worst, t = 0.0, 0.0
    for vx, vy, duration in boustrophedon():
        for _ in range(round(duration / CONTROL_DT)):
            yaw, gyro_z = robot.fused_yaw(), robot.gyro_z()
            command = drive.step(vx, vy, yaw_rad=yaw, gyro_z_rad_s=gyro_z, dt_s=CONTROL_DT, t=t)
            robot.step(command.speeds, CONTROL_DT)
            t += CONTROL_DT
            worst = max(worst, abs(float(robot.pose[2])))
    return worst / DEG, float(robot.pose[1])


def test_simulated_robot_drifts_without_heading_hold() -> None:
    worst_deg, _ = run_survey(NO_HOLD)
    assert worst_deg > 3.0


def test_heading_hold_keeps_yaw_within_half_a_degree_over_a_survey() -> None:
    worst_deg, final_y = run_survey(HeadingHoldGains())
    assert worst_deg <= 0.5
    # 9 sideways steps of 0.1 m, short by the −1 % radius error of the sideways wheels and the ramps.
    assert final_y == pytest.approx(0.9, abs=0.05)
