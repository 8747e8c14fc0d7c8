"""Heading hold: the robot never rotates, so ω comes only from a PI loop that keeps yaw at its target.

The GPR antenna must keep its orientation, so the public motion API (`HeadingHoldDrive.step`) takes a
body velocity (vx, vy) only; the yaw rate is added here to cancel the drift that wheel imbalance and
slip cause. Pure: the time step comes in as an argument.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gprbot.config import MotorsConfig
from gprbot.messages import WheelSpeeds
from gprbot.motion.kinematics import (
    FloatArray,
    KiwiKinematics,
    limit_wheel_acceleration,
    saturate_wheel_speeds,
    wrap_angle,
)


@dataclass(frozen=True)
class HeadingHoldGains:
    """Gains and limit of the heading-hold loop (ω = kp·e + ki·∫e − kd·gyro_z, |ω| ≤ max)."""

    kp_per_s: float = 3.0
    ki_per_s2: float = 1.5
    kd_gyro: float = 0.05
    max_omega_rad_s: float = 0.2

    def __post_init__(self) -> None:
        for name in ("kp_per_s", "ki_per_s2", "kd_gyro", "max_omega_rad_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"heading hold {name} must be a finite number ≥ 0, got {value!r}")


class HeadingHold:
    """A PI controller on yaw error with gyro-z damping, output clamp and conditional-integration
    anti-windup (the integral stops growing while the output is saturated in the error's direction)."""

    def __init__(self, gains: HeadingHoldGains | None = None, target_yaw_rad: float = 0.0) -> None:
        self.gains = gains or HeadingHoldGains()
        self.target_yaw_rad = target_yaw_rad
        self.integral_rad_s = 0.0  # the integral term ki·∫e, in output units
        self.last_error_rad = 0.0
        self.last_omega_rad_s = 0.0

    def reset(self, target_yaw_rad: float = 0.0) -> None:
        """Hold a new target yaw (the yaw at survey start) and clear the integral."""
        self.target_yaw_rad = target_yaw_rad
        self.integral_rad_s = 0.0
        self.last_error_rad = 0.0
        self.last_omega_rad_s = 0.0

    def update(self, yaw_rad: float, gyro_z_rad_s: float, dt_s: float) -> float:
        """The yaw-rate command (rad/s, CCW positive) from the fused yaw and the gyro's z rate."""
        if not (math.isfinite(yaw_rad) and math.isfinite(gyro_z_rad_s)):
            raise ValueError(f"heading hold needs finite yaw and gyro, got {yaw_rad!r}, {gyro_z_rad_s!r}")
        if not (math.isfinite(dt_s) and dt_s >= 0.0):
            raise ValueError(f"dt_s must be a finite non-negative time step, got {dt_s!r}")
        g = self.gains
        limit = g.max_omega_rad_s
        error = wrap_angle(self.target_yaw_rad - yaw_rad)
        candidate = min(max(self.integral_rad_s + g.ki_per_s2 * error * dt_s, -limit), limit)
        unclamped = g.kp_per_s * error + candidate - g.kd_gyro * gyro_z_rad_s
        pushing_further = (unclamped > limit and error > 0.0) or (unclamped < -limit and error < 0.0)
        if not pushing_further:
            self.integral_rad_s = candidate
        raw = g.kp_per_s * error + self.integral_rad_s - g.kd_gyro * gyro_z_rad_s
        omega = min(max(raw, -limit), limit)
        self.last_error_rad, self.last_omega_rad_s = error, omega
        return omega


class HeadingHoldDrive:
    """The public motion API: a body velocity (vx, vy) in, wheel speeds out, ω from heading hold only.

    Each step adds the heading-hold ω, applies inverse kinematics, scales all wheels to the speed
    limit (direction kept) and ramps them under the acceleration limit.
    """

    def __init__(
        self,
        kinematics: KiwiKinematics,
        max_wheel_speed_rad_s: float,
        max_wheel_accel_rad_s2: float,
        hold: HeadingHold | None = None,
    ) -> None:
        self.kinematics = kinematics
        self.max_wheel_speed_rad_s = max_wheel_speed_rad_s
        self.max_wheel_accel_rad_s2 = max_wheel_accel_rad_s2
        self.hold = hold or HeadingHold()
        self.wheel_speeds: FloatArray = np.zeros(3)

    @classmethod
    def from_config(cls, motors: MotorsConfig, gains: HeadingHoldGains | None = None) -> HeadingHoldDrive:
        """A drive with r, d and the wheel limits from the motors section of the config."""
        return cls(
            KiwiKinematics.from_config(motors),
            motors.max_wheel_speed_rad_s,
            motors.max_wheel_accel_rad_s2,
            HeadingHold(gains),
        )

    def reset(self, target_yaw_rad: float = 0.0) -> None:
        """Hold a new target yaw (call at survey start with the current fused yaw)."""
        self.hold.reset(target_yaw_rad)

    def step(
        self, vx: float, vy: float, *, yaw_rad: float, gyro_z_rad_s: float, dt_s: float, t: float
    ) -> WheelSpeeds:
        """Wheel speeds to command at time t for body velocity (vx, vy) m/s, given the fused yaw and gyro."""
        omega = self.hold.update(yaw_rad, gyro_z_rad_s, dt_s)
        target = self.kinematics.wheel_speeds((vx, vy, omega))
        target = saturate_wheel_speeds(target, self.max_wheel_speed_rad_s)
        self.wheel_speeds = limit_wheel_acceleration(
            target, self.wheel_speeds, self.max_wheel_accel_rad_s2, dt_s
        )
        return WheelSpeeds(t=t, speeds=self.wheel_speeds.copy())
