"""Ground-truth motion of the simulated robot base: the source every simulated sensor samples.

Planar motion comes from a 200 Hz dynamics loop — a velocity command (plan feed-forward plus
position feedback, or a jog) through a first-order motor lag with an acceleration limit — whose
acceleration is held constant over each step, so position, velocity and acceleration are exact at
any time. Height, roll, pitch and yaw are fields over the floor (sums of plane waves: bumps, slope,
the residual yaw wobble that heading hold leaves), so they change only while the robot moves and
their time derivatives (for the IMU) are analytic. Frames: odom (REP-105) and base_link (REP-103).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from gprbot.messages import Pose
from gprbot.motion.planner import SurveyPlan

FloatArray = NDArray[np.float64]
GRAVITY_M_S2 = 9.80665
STEP_S = 0.005


@dataclass(frozen=True)
class FloorWaves:
    """A field over the floor: value(p) = Σ a_k sin(k_k · p + φ_k), p in metres (odom x, y)."""

    amplitude: FloatArray
    wavevector: FloatArray  # (K, 2) rad/m
    phase: FloatArray

    @classmethod
    def random(
        cls, rng: np.random.Generator, rms: float, wavelengths_m: tuple[float, float], count: int = 8
    ) -> FloorWaves:
        """Random waves with log-uniform wavelengths and a given RMS over the floor."""
        wavelength = np.exp(rng.uniform(math.log(wavelengths_m[0]), math.log(wavelengths_m[1]), count))
        heading = rng.uniform(0.0, 2.0 * math.pi, count)
        k = (2.0 * math.pi / wavelength)[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
        amplitude = np.full(count, rms * math.sqrt(2.0 / count))  # RMS of Σ a sin = sqrt(Σ a²/2)
        return cls(amplitude, k, rng.uniform(0.0, 2.0 * math.pi, count))

    @classmethod
    def flat(cls) -> FloorWaves:
        """A field that is zero everywhere."""
        return cls(np.zeros(0), np.zeros((0, 2)), np.zeros(0))

    def derivatives(self, p: FloatArray, v: FloatArray, a: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Value, rate and second rate along a path at position p, velocity v, acceleration a (n, 2)."""
        arg = p @ self.wavevector.T + self.phase
        s, c = np.sin(arg), np.cos(arg)
        kv = v @ self.wavevector.T
        ka = a @ self.wavevector.T
        value = s @ self.amplitude
        rate = (c * kv) @ self.amplitude
        rate2 = (c * ka - s * kv * kv) @ self.amplitude
        return value, rate, rate2


@dataclass(frozen=True)
class DynamicsLimits:
    """How the base follows a velocity command."""

    max_speed_m_s: float = 0.3
    max_accel_m_s2: float = 0.5
    max_jerk_m_s3: float = 5.0  # motor current rise and drivetrain compliance: force does not jump
    motor_lag_s: float = 0.15
    position_gain_per_s: float = 2.0


@dataclass(frozen=True)
class GroundTruth:
    """True base_link motion in the odom frame, queried at any time within [t_start, t_end]."""

    grid_t: FloatArray
    grid_pos: FloatArray
    grid_vel: FloatArray
    grid_acc: FloatArray  # held over [t_k, t_k+1)
    height: FloorWaves
    roll: FloorWaves
    pitch: FloorWaves
    yaw: FloorWaves

    @property
    def t_start(self) -> float:
        """First time of the trajectory (s)."""
        return float(self.grid_t[0])

    @property
    def t_end(self) -> float:
        """Last time of the trajectory (s)."""
        return float(self.grid_t[-1])

    def planar(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Planar position, velocity and acceleration (n, 2) at times t (exact: piecewise quadratic)."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=np.float64)), self.t_start, self.t_end)
        k = np.clip(np.searchsorted(self.grid_t, t, side="right") - 1, 0, self.grid_t.size - 1)
        tau = (t - self.grid_t[k])[:, None]
        acc = self.grid_acc[k]
        return self.grid_pos[k] + self.grid_vel[k] * tau + 0.5 * acc * tau**2, self.grid_vel[k] + acc * tau, acc

    def _fields(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, dict[str, tuple[FloatArray, ...]]]:
        p, v, a = self.planar(t)
        named = {name: getattr(self, name).derivatives(p, v, a) for name in ("height", "roll", "pitch", "yaw")}
        return p, v, a, named

    def position(self, t: FloatArray) -> FloatArray:
        """Base position (n, 3) in odom."""
        p, _, _, f = self._fields(t)
        return np.column_stack([p, f["height"][0]])

    def velocity(self, t: FloatArray) -> FloatArray:
        """Base velocity (n, 3) in odom."""
        _, v, _, f = self._fields(t)
        return np.column_stack([v, f["height"][1]])

    def acceleration(self, t: FloatArray) -> FloatArray:
        """Base acceleration (n, 3) in odom."""
        _, _, a, f = self._fields(t)
        return np.column_stack([a, f["height"][2]])

    def euler(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Roll, pitch, yaw (rad), Z-Y-X convention: R = Rz(yaw) Ry(pitch) Rx(roll)."""
        _, _, _, f = self._fields(t)
        return f["roll"][0], f["pitch"][0], f["yaw"][0]

    def rotation(self, t: FloatArray) -> FloatArray:
        """R_odom_base (n, 3, 3)."""
        roll, pitch, yaw = self.euler(t)
        return euler_zyx_matrices(roll, pitch, yaw)

    def angular_velocity(self, t: FloatArray) -> FloatArray:
        """Body-frame angular velocity (n, 3) rad/s from the Z-Y-X Euler rates."""
        _, _, _, f = self._fields(t)
        (phi, dphi, _), (theta, dtheta, _), (_, dpsi, _) = f["roll"], f["pitch"], f["yaw"]
        sp, cp, st, ct = np.sin(phi), np.cos(phi), np.sin(theta), np.cos(theta)
        return np.column_stack(
            [dphi - dpsi * st, dtheta * cp + dpsi * sp * ct, -dtheta * sp + dpsi * cp * ct]
        )

    def specific_force(self, t: FloatArray) -> FloatArray:
        """What an ideal accelerometer at the base origin reads (n, 3): R^T (a - g), g = (0, 0, -9.81)."""
        acc = self.acceleration(t)
        acc[:, 2] += GRAVITY_M_S2
        return np.asarray(np.einsum("nji,nj->ni", self.rotation(t), acc), dtype=np.float64)

    def body_velocity(self, t: FloatArray) -> FloatArray:
        """Base velocity (n, 3) in base_link."""
        return np.asarray(np.einsum("nji,nj->ni", self.rotation(t), self.velocity(t)), dtype=np.float64)

    def poses(self, t: FloatArray) -> list[Pose]:
        """Pose messages at times t."""
        positions, quats = self.position(t), Rotation.from_matrix(self.rotation(t)).as_quat()
        return [Pose(float(ti), positions[i], quats[i]) for i, ti in enumerate(np.atleast_1d(t))]


def euler_zyx_matrices(roll: FloatArray, pitch: FloatArray, yaw: FloatArray) -> FloatArray:
    """Rotation matrices Rz(yaw) Ry(pitch) Rx(roll), shape (n, 3, 3)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
            np.stack([-sp, cp * sr, cp * cr], axis=-1),
        ],
        axis=-2,
    )


def _drive(
    cmd_vel: FloatArray, cmd_pos: FloatArray | None, start: FloatArray, limits: DynamicsLimits
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Integrate the base's response to a velocity command on the STEP_S grid."""
    n = cmd_vel.shape[0]
    pos, vel, acc = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros((n, 2))
    px, py, vx, vy, ax, ay = float(start[0]), float(start[1]), 0.0, 0.0, 0.0, 0.0
    gain, lag, amax, vmax, dt = (limits.position_gain_per_s, limits.motor_lag_s, limits.max_accel_m_s2,
                                 limits.max_speed_m_s, STEP_S)
    max_change = limits.max_jerk_m_s3 * dt
    for k in range(n):
        pos[k] = px, py
        vel[k] = vx, vy
        cx, cy = cmd_vel[k]
        if cmd_pos is not None:
            cx += gain * (cmd_pos[k, 0] - px)
            cy += gain * (cmd_pos[k, 1] - py)
        speed = math.hypot(cx, cy)
        if speed > vmax:
            cx, cy = cx * vmax / speed, cy * vmax / speed
        wx, wy = (cx - vx) / lag, (cy - vy) / lag
        mag = math.hypot(wx, wy)
        if mag > amax:
            wx, wy = wx * amax / mag, wy * amax / mag
        change = math.hypot(wx - ax, wy - ay)
        if change > max_change:
            wx, wy = ax + (wx - ax) * max_change / change, ay + (wy - ay) * max_change / change
        ax, ay = wx, wy
        acc[k] = ax, ay
        px, py = px + vx * dt + 0.5 * ax * dt * dt, py + vy * dt + 0.5 * ay * dt * dt
        vx, vy = vx + ax * dt, vy + ay * dt
    return pos, vel, acc


def _with_floor(grid_t: FloatArray, pos: FloatArray, vel: FloatArray, acc: FloatArray, seed: int,
                rough: bool) -> GroundTruth:
    rng = np.random.default_rng(seed)
    if not rough:
        flat = FloorWaves.flat()
        return GroundTruth(grid_t, pos, vel, acc, flat, flat, flat, flat)
    return GroundTruth(
        grid_t, pos, vel, acc,
        height=FloorWaves.random(rng, 0.2e-3, (0.05, 1.0)),  # floor bumps and roller ripple, 0.2 mm RMS
        roll=FloorWaves.random(rng, math.radians(0.15), (0.3, 3.0)),
        pitch=FloorWaves.random(rng, math.radians(0.15), (0.3, 3.0)),
        yaw=FloorWaves.random(rng, math.radians(0.1), (0.2, 2.0)),  # what heading hold leaves
    )


def survey_ground_truth(plan: SurveyPlan, lever_arm_xy: tuple[float, float] = (0.25, 0.0), seed: int = 0,
                        limits: DynamicsLimits | None = None, tail_s: float = 1.0, rough: bool = True) -> GroundTruth:
    """The base driving a survey plan (made for the antenna, offset by the lever arm) with real dynamics."""
    limits = limits or DynamicsLimits()
    grid_t = np.arange(0.0, plan.duration_s + tail_s, STEP_S)
    arm = np.asarray(lever_arm_xy, dtype=np.float64)
    target = plan.position(grid_t) - arm
    pos, vel, acc = _drive(plan.velocity(grid_t), target, target[0], limits)
    return _with_floor(grid_t, pos, vel, acc, seed, rough)


def straight_ground_truth(duration_s: float, velocity_m_s: tuple[float, float], rest_s: float = 1.0, seed: int = 0,
                          rough: bool = True) -> GroundTruth:
    """Rest, then a constant-velocity run (after the acceleration ramp) until duration_s."""
    grid_t = np.arange(0.0, duration_s, STEP_S)
    cmd = np.where((grid_t >= rest_s)[:, None], np.asarray(velocity_m_s), 0.0)
    pos, vel, acc = _drive(cmd, None, np.zeros(2), DynamicsLimits())
    return _with_floor(grid_t, pos, vel, acc, seed, rough)


def jog_ground_truth(duration_s: float = 300.0, seed: int = 0, box_m: float = 1.2,
                     speeds_m_s: tuple[float, float] = (0.05, 0.25), rough: bool = True) -> GroundTruth:
    """A random jog: forward, backward or sideways moves of random speed and length, with pauses."""
    rng = np.random.default_rng(seed + 7919)
    grid_t = np.arange(0.0, duration_s, STEP_S)
    cmd = np.zeros((grid_t.size, 2))
    t, planned = 1.0, np.zeros(2)
    axes = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    while t < duration_s - 2.0:
        direction = axes[rng.integers(4)]
        if np.max(np.abs(planned)) > box_m:  # head back towards the middle of the floor
            k = int(np.argmax(np.abs(planned)))
            direction = -np.sign(planned[k]) * np.eye(2)[k]
        speed, length = rng.uniform(*speeds_m_s), rng.uniform(1.0, 5.0)
        end = min(t + length, duration_s - 2.0)
        cmd[(grid_t >= t) & (grid_t < end)] = speed * direction
        planned += speed * direction * (end - t)
        t = end + rng.uniform(0.0, 1.5)
    pos, vel, acc = _drive(cmd, None, np.zeros(2), DynamicsLimits())
    return _with_floor(grid_t, pos, vel, acc, seed, rough)
