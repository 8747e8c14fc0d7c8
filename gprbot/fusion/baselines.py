"""Single-source pose estimates the fused filter is judged against: wheels only, VO only, IMU only.

Each starts from the same known start pose as the filter and uses its sensor the way a system with
only that sensor would: wheel odometry integrates the nominal kiwi kinematics; VO chains its
keyframe motions (not the map keyframes it finds again) and, where it lost track, carries on at its
last velocity (it has nothing else); IMU dead reckoning is a strapdown integration after the same
at-rest initialisation as the filter.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from gprbot.config import MotorsConfig
from gprbot.fusion.so3 import FloatArray, exp_so3, gravity_aligned, log_so3, matrix_to_quat, quat_to_matrix
from gprbot.messages import ImuSample, Pose, VoMeasurement, WheelSpeeds
from gprbot.motion.kinematics import KiwiKinematics, WheelOdometry

GRAVITY = np.array([0.0, 0.0, -9.80665])


def _pose(t: float, p: FloatArray, R: FloatArray) -> Pose:
    return Pose(t, np.asarray(p, dtype=np.float64).copy(), matrix_to_quat(R))


def _yaw_matrix(yaw: float) -> FloatArray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def wheel_only(messages: Sequence[WheelSpeeds], motors: MotorsConfig, start: FloatArray, yaw: float) -> list[Pose]:
    """Planar wheel odometry (gprbot.motion.kinematics.WheelOdometry) from the start pose."""
    odometry = WheelOdometry(KiwiKinematics.from_config(motors), (float(start[0]), float(start[1]), yaw))
    out = []
    for m in messages:
        x, y, heading = odometry.update(m)
        out.append(_pose(m.t, np.array([x, y, start[2]]), _yaw_matrix(heading)))
    return out


def vo_only(measurements: Sequence[VoMeasurement], start: FloatArray, yaw: float, t0: float) -> list[Pose]:
    """Chained VO motions; across tracking gaps the last measured velocity is assumed."""
    out = [_pose(t0, start, _yaw_matrix(yaw))]
    p, R, ref_t = np.asarray(start, dtype=np.float64), _yaw_matrix(yaw), t0
    ref_p, ref_R = p.copy(), R.copy()
    velocity, rate = np.zeros(3), np.zeros(3)  # body frame, per second
    tracking = False
    for m in sorted(measurements, key=lambda m: m.t):
        if m.revisit_slot >= 0:  # a map keyframe seen again: VO alone keeps no map to put it against
            continue
        if m.status == "ok" and tracking and abs(m.t_ref - ref_t) < 1e-6:
            dR, dt = quat_to_matrix(m.rotation), max(m.t - m.t_ref, 1e-6)
            p, R = ref_p + ref_R @ m.translation, ref_R @ dR
            velocity, rate = m.translation / dt, log_so3(dR) / dt
            out.append(_pose(m.t, p, R))
            tracking = False
        elif m.t > out[-1].t:  # a gap: coast at the last velocity up to this message
            dt = m.t - out[-1].t
            p, R = p + R @ velocity * dt, R @ exp_so3(rate * dt)
            out.append(_pose(m.t, p, R))
        if m.new_keyframe:
            ref_t, ref_p, ref_R, tracking = m.t, p.copy(), R.copy(), True
    return out


def imu_dead_reckoning(messages: Sequence[ImuSample], start: FloatArray, yaw: float, init_s: float) -> list[Pose]:
    """Strapdown integration of gyro and accel, bias and tilt from the first init_s at rest."""
    t0 = messages[0].t
    rest = [m for m in messages if m.t - t0 < init_s]
    gyro_bias = np.mean([m.gyro for m in rest if m.gyro is not None], axis=0)
    f = np.mean([m.accel for m in rest if m.accel is not None], axis=0)
    R = gravity_aligned(f, yaw)
    p, v = np.asarray(start, dtype=np.float64).copy(), np.zeros(3)
    gyro, accel, t = gyro_bias.copy(), f.copy(), rest[-1].t
    out = []
    for m in messages:
        if m.t < t:
            continue
        dt = m.t - t
        if dt > 0.0:
            acc = R @ accel + GRAVITY
            p, v, R = p + v * dt + 0.5 * acc * dt * dt, v + acc * dt, R @ exp_so3((gyro - gyro_bias) * dt)
            t = m.t
        if m.gyro is not None:
            gyro = m.gyro
            out.append(_pose(t, p, R))
        if m.accel is not None:
            accel = m.accel
    return out
