"""Kiwi-drive kinematics: body twist ↔ wheel speeds, speed/acceleration limits, wheel odometry.

Conventions (REP-103): body frame x forward, y left, z up; ω is the yaw rate about +z,
counter-clockwise positive. A twist is the array (vx m/s, vy m/s, ω rad/s); a planar pose is
(x m, y m, yaw rad) in the site frame.

Inverse kinematics is the paper's matrix (Feng et al., eq. for the three-wheel omni base):

    w = (1/r) · [[1, 0, −d], [cos 2π/3, sin 2π/3, −d], [cos −2π/3, sin −2π/3, −d]] · (vx, vy, ω)

Row i says: wheel i's rim speed is the body velocity along its drive direction u_i = (cos θ_i, sin θ_i),
θ_i ∈ (0, 2π/3, −2π/3), minus d·ω. That holds, with ω counter-clockwise positive, for wheel i mounted
at bearing θ_i + 90° from +x (wheel 0 on the left at (0, d), wheel 1 rear-right, wheel 2 front-right)
with positive spin driving its rim along u_i: a CCW spin moves each contact point along −u_i at d·ω.
The row order is the order of MotorsConfig.wheel_map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gprbot.config import MotorsConfig
from gprbot.errors import ConfigError
from gprbot.messages import Pose, WheelSpeeds

FloatArray = NDArray[np.float64]

WHEEL_DRIVE_ANGLES_RAD = (0.0, 2.0 * math.pi / 3.0, -2.0 * math.pi / 3.0)


def kiwi_matrix(base_radius_m: float) -> FloatArray:
    """The 3×3 matrix mapping a body twist to wheel rim speeds (m/s), before dividing by r."""
    return np.array(
        [[math.cos(a), math.sin(a), -base_radius_m] for a in WHEEL_DRIVE_ANGLES_RAD], dtype=np.float64
    )


@dataclass(frozen=True)
class KiwiKinematics:
    """Inverse and forward kinematics of the three-omni-wheel base."""

    wheel_radius_m: float
    base_radius_m: float
    _rim_from_twist: FloatArray = field(init=False, repr=False, compare=False)
    _twist_from_rim: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("wheel_radius_m", "base_radius_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"motors.{name}: must be a positive length in metres, got {value!r}")
        matrix = kiwi_matrix(self.base_radius_m)
        # Least-squares inverse; for three wheels at 120° it is the exact inverse.
        object.__setattr__(self, "_rim_from_twist", matrix)
        object.__setattr__(self, "_twist_from_rim", np.linalg.pinv(matrix))

    @classmethod
    def from_config(cls, motors: MotorsConfig) -> KiwiKinematics:
        """Kinematics with r and d from the motors section of the config."""
        return cls(wheel_radius_m=motors.wheel_radius_m, base_radius_m=motors.base_radius_m)

    def wheel_speeds(self, twist: ArrayLike) -> FloatArray:
        """Inverse kinematics: wheel angular speeds (rad/s) for a body twist (vx, vy, ω)."""
        return (self._rim_from_twist @ _vector(twist, 3, "twist")) / self.wheel_radius_m

    def body_twist(self, wheel_speeds: ArrayLike) -> FloatArray:
        """Forward kinematics: the body twist (vx, vy, ω) that measured wheel speeds (rad/s) imply."""
        rim = _vector(wheel_speeds, 3, "wheel speeds") * self.wheel_radius_m
        return self._twist_from_rim @ rim


def saturate_wheel_speeds(speeds: ArrayLike, max_speed_rad_s: float) -> FloatArray:
    """Scale all wheels by one factor so none exceeds the limit; the twist's direction is kept."""
    w = _vector(speeds, 3, "wheel speeds")
    peak = float(np.max(np.abs(w)))
    if peak <= max_speed_rad_s:
        return w.copy()
    return w * (max_speed_rad_s / peak)


def limit_wheel_acceleration(
    target: ArrayLike, previous: ArrayLike, max_accel_rad_s2: float, dt_s: float
) -> FloatArray:
    """Move from `previous` towards `target` by at most max_accel·dt per wheel, scaling all alike.

    The change (target − previous) is scaled by one common factor, so the twist changes along a
    straight line in twist space: starting from rest or along the current direction, the direction
    of travel is kept; a turn of direction is blended over the ramp.
    """
    goal = _vector(target, 3, "target wheel speeds")
    start = _vector(previous, 3, "previous wheel speeds")
    if dt_s < 0.0 or not math.isfinite(dt_s):
        raise ValueError(f"dt_s must be a finite non-negative time step, got {dt_s!r}")
    change = goal - start
    peak = float(np.max(np.abs(change)))
    allowed = max_accel_rad_s2 * dt_s
    if peak <= allowed:
        return goal.copy()
    return start + change * (allowed / peak)


def integrate_body_twist(pose: ArrayLike, twist: ArrayLike, dt_s: float) -> FloatArray:
    """Site-frame pose (x, y, yaw) after moving with a constant body twist for dt_s (exact SE(2) arc)."""
    x, y, yaw = _vector(pose, 3, "pose")
    vx, vy, omega = _vector(twist, 3, "twist")
    turn = omega * dt_s
    if abs(turn) < 1e-9:
        # Series of sin(θ)/θ and (1 − cos θ)/θ; exact to round-off for tiny turns.
        along, across = dt_s * (1.0 - turn * turn / 6.0), dt_s * turn / 2.0
    else:
        along, across = math.sin(turn) / omega, (1.0 - math.cos(turn)) / omega
    dx_body = along * vx - across * vy
    dy_body = across * vx + along * vy
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([x + c * dx_body - s * dy_body, y + s * dx_body + c * dy_body, wrap_angle(yaw + turn)])


def wrap_angle(angle_rad: float) -> float:
    """The angle wrapped into [−π, π)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def planar_pose_message(t: float, pose: ArrayLike) -> Pose:
    """A Pose message (z = 0, yaw-only quaternion) for a planar pose (x, y, yaw)."""
    x, y, yaw = _vector(pose, 3, "pose")
    return Pose(
        t=t,
        position=np.array([x, y, 0.0]),
        orientation=np.array([0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)]),
    )


class WheelOdometry:
    """Dead reckoning from measured wheel speeds (WheelSpeeds messages) into a site-frame pose."""

    def __init__(self, kinematics: KiwiKinematics, initial_pose: ArrayLike = (0.0, 0.0, 0.0)) -> None:
        self.kinematics = kinematics
        self.pose: FloatArray = _vector(initial_pose, 3, "initial pose").copy()
        self.twist: FloatArray = np.zeros(3)
        self._last: WheelSpeeds | None = None

    def update(self, measured: WheelSpeeds) -> FloatArray:
        """Integrate up to measured.t with the mean twist of this and the previous sample; the pose.

        The first sample only sets the start time; a repeated or out-of-order sample (t not after
        the previous one) is ignored.
        """
        twist = self.kinematics.body_twist(measured.speeds)
        if self._last is None:
            self._last, self.twist = measured, twist
            return self.pose.copy()
        dt = measured.t - self._last.t
        if dt <= 0.0:
            return self.pose.copy()
        mean_twist = 0.5 * (self.twist + twist)
        self.pose = integrate_body_twist(self.pose, mean_twist, dt)
        self._last, self.twist = measured, twist
        return self.pose.copy()

    def pose_message(self) -> Pose:
        """The current pose as a Pose message stamped with the last sample's time."""
        t = self._last.t if self._last is not None else 0.0
        return planar_pose_message(t, self.pose)


def _vector(values: ArrayLike, length: int, what: str) -> FloatArray:
    array = np.asarray(values, dtype=np.float64)
    if array.shape != (length,):
        raise ValueError(f"{what}: expected {length} numbers, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{what}: must be finite, got {array.tolist()}")
    return array
