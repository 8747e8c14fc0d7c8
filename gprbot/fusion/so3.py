"""Small SO(3) helpers on 3×3 matrices for the filter's hot path (scipy's Rotation is too slow at 400 Hz).

Rotation vectors follow the right-perturbation convention used throughout fusion: R = R̂ · exp(δθ),
so δθ is expressed in the rotated (body) frame.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def skew(v: FloatArray) -> FloatArray:
    """The cross-product matrix [v]× such that [v]× w = v × w."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def exp_so3(phi: FloatArray) -> FloatArray:
    """Rotation matrix of a rotation vector (Rodrigues' formula, series form near zero)."""
    angle_sq = float(phi @ phi)
    K = skew(phi)
    if angle_sq < 1e-12:
        return np.eye(3) + K + 0.5 * (K @ K)
    angle = math.sqrt(angle_sq)
    return np.eye(3) + (math.sin(angle) / angle) * K + ((1.0 - math.cos(angle)) / angle_sq) * (K @ K)


def exp_so3_many(phis: FloatArray) -> FloatArray:
    """`exp_so3` of each row of an (n, 3) array at once: (n, 3, 3)."""
    angle_sq = np.einsum("ij,ij->i", phis, phis)
    K = np.zeros((len(phis), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -phis[:, 2], phis[:, 1], -phis[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = phis[:, 2], -phis[:, 1], phis[:, 0]
    small = angle_sq < 1e-12
    angle = np.sqrt(np.where(small, 1.0, angle_sq))
    a = np.where(small, 1.0, np.sin(angle) / angle)
    b = np.where(small, 0.5, (1.0 - np.cos(angle)) / np.where(small, 1.0, angle_sq))
    out: FloatArray = np.eye(3) + a[:, None, None] * K + b[:, None, None] * (K @ K)
    return out


def log_so3(R: FloatArray) -> FloatArray:
    """Rotation vector of a rotation matrix (angle below π)."""
    cos_angle = min(1.0, max(-1.0, 0.5 * (float(np.trace(R)) - 1.0)))
    angle = math.acos(cos_angle)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-6:
        return 0.5 * w
    return (angle / (2.0 * math.sin(angle))) * w


def orthonormalize(R: FloatArray) -> FloatArray:
    """The nearest rotation matrix (removes round-off accumulated by repeated products)."""
    u, _, vt = np.linalg.svd(R)
    out: FloatArray = u @ vt
    if np.linalg.det(out) < 0.0:
        u[:, -1] *= -1.0
        out = u @ vt
    return out


def matrix_to_quat(R: FloatArray) -> FloatArray:
    """Quaternion (x, y, z, w), w ≥ 0, of a rotation matrix (Shepperd's method)."""
    m = R
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = np.array([(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s])
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = np.array([0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s])
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = np.array([(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s])
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = np.array([(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s])
    q /= np.linalg.norm(q)
    return q if q[3] >= 0.0 else -q


def quat_to_matrix(q: FloatArray) -> FloatArray:
    """Rotation matrix of a quaternion (x, y, z, w)."""
    x, y, z, w = np.asarray(q, dtype=np.float64) / float(np.linalg.norm(q))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def gravity_aligned(mean_accel: FloatArray, yaw: float) -> FloatArray:
    """R_odom_base of a body at rest: roll and pitch level the measured specific force, yaw is given."""
    fx, fy, fz = (float(v) for v in mean_accel)
    roll, pitch = math.atan2(fy, fz), math.atan2(-fx, math.hypot(fy, fz))
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], [-sp, cp * sr, cp * cr]])


def yaw_of(R: FloatArray) -> float:
    """Heading (rad) of a body frame: the angle of its x axis projected on the odom x-y plane."""
    return math.atan2(float(R[1, 0]), float(R[0, 0]))
