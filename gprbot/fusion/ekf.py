"""The loosely coupled error-state EKF: IMU propagation, wheel and visual-odometry updates (filterpy).

Frames (REP-103/105): `odom` is fixed to the start pose (x forward, y left, z up, gravity along −z);
`base_link` is the robot body. The IMU and wheel samples arrive in base_link (the drivers rotate the
sensors' axes once); VO arrives as base_link motion (see fusion.vo).

Nominal state: position p (m, odom), velocity v (m/s, odom), attitude R = R_odom_base, gyro bias b_g
(rad/s, base_link), accel bias b_a (m/s², base_link), per-wheel radius error s (fraction: the true
radius is r·(1 + s_i)), a clone (p_c, R_c) of the pose at the current VO keyframe, and one clone per
map keyframe slot (fusion.vo_map: floor seen before; `vo_map_slots` of them).
Error state (24 + 6 per slot, held in a filterpy KalmanFilter; its predict and update are written out
here, as the slots' part of them is copies and zeros): δp, δv, δθ (R = R̂ Exp(δθ)), δb_g, δb_a, δs,
δp_c, δθ_c, then (δp, δθ) of each slot. Propagation is the standard ESKF (Solà, "Quaternion kinematics
for the error-state Kalman filter", 2017, §5); VO is a relative-pose measurement between the clone and now (stochastic
cloning, Roumeliotis & Burdick 2002); wheels measure the three rim speeds, 1st-order in δs, with
their common mode (the rotation) projected out: see `update_wheels`.
"""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import KalmanFilter
from scipy.stats import chi2

from gprbot.config import FusionConfig
from gprbot.fusion.so3 import (
    FloatArray,
    exp_so3,
    exp_so3_many,
    gravity_aligned,
    log_so3,
    orthonormalize,
    quat_to_matrix,
    skew,
)
from gprbot.messages import VoMeasurement
from gprbot.motion.kinematics import KiwiKinematics, kiwi_matrix

GRAVITY = np.array([0.0, 0.0, -9.80665])
POS, VEL, ATT, BG, BA, WS, CPOS, CATT = (slice(i, i + 3) for i in range(0, 24, 3))
DIM = 24
# Rows orthogonal to (1, 1, 1): the three rim speeds' differential part. On a kiwi base the drive
# directions sum to zero, so the common mode of the rims is −3·d·ω (rotation) and the rest is translation.
_DIFFERENTIAL = np.array([[1.0, -1.0, 0.0], [1.0, 1.0, -2.0]]) / np.sqrt([[2.0], [6.0]])


class VelocityChanges:
    """The IMU's integrated velocity change (odom) at each propagation step of the last second or so.

    Lets a measurement sampled shortly before the state time be compared with the velocity then:
    v(t_i) ≈ v − (Δv(now) − Δv(t_i)), with the IMU's own change and not the filter's corrections.
    """

    SIZE = 160  # propagation steps kept (1.6 s at the default 10 ms step)

    def __init__(self) -> None:
        self.t = np.full(self.SIZE, -math.inf)
        self.dv = np.zeros((self.SIZE, 3))
        self.total = np.zeros(3)
        self.index = 0

    def add(self, t: float, dv: FloatArray) -> None:
        """One propagation step ending at t."""
        self.total = self.total + dv
        self.t[self.index], self.dv[self.index] = t, self.total
        self.index = (self.index + 1) % self.SIZE

    def since(self, times: FloatArray) -> FloatArray:
        """Δv from each time to the newest step (rows); 0 before the first step, the oldest kept beyond."""
        order = (np.arange(self.SIZE) + self.index) % self.SIZE
        t, dv = self.t[order], self.dv[order]
        kept = np.isfinite(t)
        if kept.sum() < 2:
            return np.zeros((len(times), 3))
        t, dv = t[kept], dv[kept]
        at = np.column_stack([np.interp(times, t, dv[:, k]) for k in range(3)])
        change: FloatArray = dv[-1] - at
        return change

    def arrays(self) -> dict[str, FloatArray]:
        """Its state, for the fusion snapshot."""
        return {"dv_t": self.t.copy(), "dv": self.dv.copy(), "dv_total": self.total.copy(),
                "dv_index": np.array([float(self.index)])}

    def load(self, arrays: dict[str, FloatArray]) -> None:
        """Restore `arrays()` (a snapshot from before it existed leaves it empty)."""
        if "dv_t" in arrays:
            self.t, self.dv, self.total = arrays["dv_t"].copy(), arrays["dv"].copy(), arrays["dv_total"].copy()
            self.index = int(arrays["dv_index"][0])


class ErrorStateEkf:
    """The filter proper: time-ordered calls only (PoseFuser does the ordering)."""

    def __init__(self, config: FusionConfig, kinematics: KiwiKinematics) -> None:
        self.config = config
        self.kinematics = kinematics
        self._drive = kiwi_matrix(kinematics.base_radius_m)  # rows (cos θ_i, sin θ_i, −d)
        self.slots = config.vo_map_slots
        self.dim = DIM + 6 * self.slots
        self.kf = KalmanFilter(dim_x=self.dim, dim_z=6)
        self.t = math.nan
        self.p, self.v = np.zeros(3), np.zeros(3)
        self.R = np.eye(3)
        self.gyro_bias, self.accel_bias, self.wheel_scale = np.zeros(3), np.zeros(3), np.zeros(3)
        self.clone_p, self.clone_R, self.clone_t = np.zeros(3), np.eye(3), math.nan
        self.slot_p, self.slot_R = np.zeros((self.slots, 3)), np.tile(np.eye(3), (self.slots, 1, 1))
        self.slot_t = np.full(self.slots, math.nan)
        self.gyro, self.accel = np.zeros(3), -GRAVITY.copy()
        self.floor_z = 0.0
        self._held_since = math.nan  # inputs are integrated (held) from here on
        self._sum_gyro, self._sum_accel = np.zeros(3), np.zeros(3)
        self.velocity_changes = VelocityChanges()
        self._F = np.eye(DIM)
        self._I3 = np.eye(3)
        c = config
        self._q_rate = np.concatenate([
            np.zeros(3), np.full(3, c.accel_noise_m_s2_sqrt_hz**2), np.full(3, c.gyro_noise_rad_s_sqrt_hz**2),
            np.full(3, c.gyro_bias_walk_rad_s2_sqrt_hz**2), np.full(3, c.accel_bias_walk_m_s3_sqrt_hz**2),
            np.full(3, c.wheel_scale_walk_per_sqrt_s**2), np.zeros(6),
        ])
        self._pose_rows = np.r_[POS, ATT]
        self._gate = {m: float(chi2.ppf(c.gate_probability, m)) for m in (3, 4, 6)}
        self.rejected_in_a_row: dict[str, int] = {"wheels": 0, "vo": 0, "revisit": 0}

    @property
    def initialized(self) -> bool:
        """Whether `initialize` has run."""
        return not math.isnan(self.t)

    def initialize(self, t: float, mean_accel: FloatArray, mean_gyro: FloatArray, position: FloatArray,
                   yaw: float) -> None:
        """Start at rest: roll and pitch from gravity, gyro bias from the mean rate at rest, yaw given."""
        self.R = gravity_aligned(mean_accel, yaw)
        self.p, self.v = np.asarray(position, dtype=np.float64).copy(), np.zeros(3)
        self.floor_z = float(self.p[2])
        self.gyro_bias = np.asarray(mean_gyro, dtype=np.float64).copy()
        self.accel_bias, self.wheel_scale = np.zeros(3), np.zeros(3)
        self.gyro, self.accel, self.t = self.gyro_bias.copy(), np.asarray(mean_accel, dtype=np.float64).copy(), t
        self._held_since = t
        self._sum_gyro, self._sum_accel = np.zeros(3), np.zeros(3)
        c = self.config
        tilt, yaw_std = math.radians(c.initial_tilt_std_deg), math.radians(c.initial_yaw_std_deg)
        std = np.concatenate([
            np.full(3, c.initial_position_std_m), np.full(3, c.initial_velocity_std_m_s), [tilt, tilt, yaw_std],
            np.full(3, c.initial_gyro_bias_std_rad_s), np.full(3, c.initial_accel_bias_std_m_s2),
            np.full(3, c.initial_wheel_scale_std), np.full(6 + 6 * self.slots, 1e-6),
        ])
        self.kf.x = np.zeros((self.dim, 1))
        self.kf.P = np.diag(std**2)
        self.clone_t = math.nan
        self.slot_t = np.full(self.slots, math.nan)

    def add_imu(self, t: float, gyro: FloatArray | None, accel: FloatArray | None) -> None:
        """Take an IMU reading at t (held until the next one); propagate once a step's worth has gathered."""
        self._hold_until(t)
        if gyro is not None:
            self.gyro = np.asarray(gyro, dtype=np.float64)
        if accel is not None:
            self.accel = np.asarray(accel, dtype=np.float64)
        if t - self.t >= self.config.propagation_step_s:
            self.propagate_to(t)

    def _hold_until(self, t: float) -> None:
        dt = t - self._held_since
        if dt > 0.0:
            self._sum_gyro += self.gyro * dt
            self._sum_accel += self.accel * dt
            self._held_since = t

    def propagate_to(self, t: float) -> None:
        """Integrate the IMU readings (mean rate and specific force since the state time) up to t."""
        self._hold_until(t)
        dt = t - self.t
        if dt <= 0.0:
            return
        omega = self._sum_gyro / dt - self.gyro_bias
        acc_body = self._sum_accel / dt - self.accel_bias
        self._sum_gyro, self._sum_accel = np.zeros(3), np.zeros(3)
        acc = self.R @ acc_body + GRAVITY
        step = exp_so3(omega * dt)
        F = self._F.copy()
        F[POS, VEL] = self._I3 * dt
        F[VEL, ATT] = -self.R @ skew(acc_body) * dt
        F[VEL, BA] = -self.R * dt
        F[ATT, ATT] = step.T
        F[ATT, BG] = self._I3 * -dt
        self._predict(F, self._q_rate[:DIM] * dt)
        self.p = self.p + self.v * dt + 0.5 * acc * dt * dt
        self.v = self.v + acc * dt
        self.R = self.R @ step
        self.t = t
        self.velocity_changes.add(t, acc * dt)

    def extrapolate(self, t: float) -> tuple[FloatArray, FloatArray]:
        """Position and attitude at a time shortly after the state time, without touching the filter."""
        dt = t - self.t
        acc = self.R @ (self.accel - self.accel_bias) + GRAVITY
        return self.p + self.v * dt + 0.5 * acc * dt * dt, self.R @ exp_so3((self.gyro - self.gyro_bias) * dt)

    def horizontal_std(self) -> tuple[float, float]:
        """1σ of the horizontal position (m, the covariance ellipse's major axis) and of the yaw (rad)."""
        P = self.kf.P
        major = float(np.linalg.eigvalsh(P[:2, :2])[-1])
        return math.sqrt(max(major, 0.0)), math.sqrt(max(float(P[ATT.start + 2, ATT.start + 2]), 0.0))

    def update_wheels(self, speeds: FloatArray, sample_offsets_s: FloatArray | None = None) -> bool:
        """The wheels' translation (rim speeds less their common mode), zero vertical body speed and the
        floor's height; False if gated. Each rim is compared with the body's velocity when it was
        sampled (`sample_offsets_s` before the state time; the IMU's change since then is known).

        The common mode of the rims is the wheels' opinion of the turn rate, and it is the wrong one
        whenever the true radii differ: commanded speeds without rotation then turn the robot, which
        the gyro sees and the encoders cannot. Fused, it pulled the yaw back towards "no turn" (and
        heading hold trusts that yaw), so yaw is left to the gyro (its bias from rest, and VO). The last
        two rows are pseudo-measurements of a robot on a level slab: without them pitch and the
        accelerometer's x bias cannot be told apart (the robot never turns), and a wrong pitch would
        tilt every VO step into a climb.
        """
        c = self.config
        v_body = self.R.T @ self.v
        omega_z = float(self.gyro[2] - self.gyro_bias[2])
        if sample_offsets_s is None or not np.any(sample_offsets_s):
            rim_true = self._drive @ np.array([v_body[0], v_body[1], omega_z])
        else:  # read one after another: each wheel against the velocity at its own instant
            then = (self.v - self.velocity_changes.since(self.t + np.asarray(sample_offsets_s))) @ self.R
            rim_true = np.einsum("ij,ij->i", self._drive, np.column_stack([then[:, :2], np.full(3, omega_z)]))
        gain = 1.0 - self.wheel_scale
        directions = np.column_stack([self._drive[:, :2], np.zeros(3)])
        rims = np.zeros((3, self.dim))
        rims[:, VEL] = gain[:, None] * (directions @ self.R.T)
        rims[:, ATT] = gain[:, None] * (directions @ skew(v_body))
        rims[:, BG.start + 2] = gain * self.kinematics.base_radius_m
        rims[:, WS] = np.diag(-rim_true)
        rim = np.asarray(speeds, dtype=np.float64) * self.kinematics.wheel_radius_m
        rim_variance = np.diag(c.wheel_rim_speed_std_m_s**2 + (c.wheel_slip_std * rim) ** 2)
        H = np.zeros((4, self.dim))
        H[:2] = _DIFFERENTIAL @ rims
        H[2, VEL] = self.R[:, 2]
        H[2, ATT] = skew(v_body)[2]
        H[3, POS.start + 2] = 1.0
        measured = np.concatenate([_DIFFERENTIAL @ rim, [0.0, self.floor_z]])
        predicted = np.concatenate([_DIFFERENTIAL @ (gain * rim_true), [v_body[2], self.p[2]]])
        R_meas = np.zeros((4, 4))
        R_meas[:2, :2] = _DIFFERENTIAL @ rim_variance @ _DIFFERENTIAL.T
        R_meas[2, 2], R_meas[3, 3] = c.vertical_speed_std_m_s**2, c.floor_height_std_m**2
        rows = 4 if c.floor_height_std_m > 0.0 else 3
        return self._update("wheels", (measured - predicted)[:rows], H[:rows], R_meas[:rows, :rows])

    def update_vo(self, m: VoMeasurement) -> str:
        """Apply a keyframe-relative VO motion; 'applied', 'rejected' (gated) or 'skipped' (no clone at t_ref).

        A revisit (`m.revisit_slot` ≥ 0) is the motion from that map slot's keyframe instead.
        """
        slot = m.revisit_slot
        if slot >= 0:
            if slot >= self.slots or not abs(self.slot_t[slot] - m.t_ref) <= 1e-6:  # nan: never stored
                return "skipped"
            ref_p, ref_R, ref = self.slot_p[slot], self.slot_R[slot], DIM + 6 * slot
        else:
            if math.isnan(self.clone_t) or abs(self.clone_t - m.t_ref) > 1e-6:
                return "skipped"
            ref_p, ref_R, ref = self.clone_p, self.clone_R, CPOS.start
        c = self.config
        rel_p = ref_R.T @ (self.p - ref_p)
        rel_R = ref_R.T @ self.R
        residual = np.concatenate([m.translation - rel_p, log_so3(rel_R.T @ quat_to_matrix(m.rotation))])
        H = np.zeros((6, self.dim))
        H[:3, POS], H[:3, ref:ref + 3], H[:3, ref + 3:ref + 6] = ref_R.T, -ref_R.T, skew(rel_p)
        H[3:, ATT], H[3:, ref + 3:ref + 6] = np.eye(3), -rel_R.T
        floor = np.concatenate([np.full(3, c.vo_translation_floor_m**2), np.full(3, c.vo_rotation_floor_rad**2)])
        R_meas = c.vo_covariance_scale * 0.5 * (m.covariance + m.covariance.T) + np.diag(floor)
        return "applied" if self._update("revisit" if slot >= 0 else "vo", residual, H, R_meas) else "rejected"

    def clone(self) -> None:
        """Remember the current pose (and its correlations) as the reference of the next VO measurement."""
        self.clone_p, self.clone_R, self.clone_t = self.p.copy(), self.R.copy(), self.t
        self._copy_pose_to(CPOS.start)

    def store_in_slot(self, slot: int) -> bool:
        """Remember the current pose (and its correlations) in a map slot; False if there is no such slot."""
        if not 0 <= slot < self.slots:
            return False
        self.slot_p[slot], self.slot_R[slot], self.slot_t[slot] = self.p, self.R, self.t
        self._copy_pose_to(DIM + 6 * slot)
        return True

    def _copy_pose_to(self, start: int) -> None:
        """Overwrite error states start..start+6 with a copy of (δp, δθ) now: P ← M P Mᵀ, done as copies."""
        P, src, dst = self.kf.P, self._pose_rows, slice(start, start + 6)
        rows = P[src, :].copy()
        P[dst, :] = rows
        P[:, dst] = rows.T
        P[dst, dst] = rows[:, src]

    def _predict(self, F: FloatArray, q: FloatArray) -> None:
        """P ← F P Fᵀ + Q with F and Q acting on the first DIM states only: the slots hold still, so only
        their cross-covariance moves (the dense product over 24 + 6·slots states would cost ~25× more)."""
        P = self.kf.P
        cross = F @ P[:DIM, DIM:]
        P[:DIM, :DIM] = F @ P[:DIM, :DIM] @ F.T + np.diag(q)
        P[:DIM, DIM:], P[DIM:, :DIM] = cross, cross.T

    def _update(self, sensor: str, residual: FloatArray, H: FloatArray, R_meas: FloatArray) -> bool:
        """One Kalman update of the error state (zero before it); False if the χ² gate turned it away.

        P ← P − K S Kᵀ with the optimal gain is filterpy's Joseph form (I − KH) P (I − KH)ᵀ + K R Kᵀ to
        round-off, at O(n²·m) instead of O(n³) for the n = 24 + 6·slots states; H's zero columns (most of
        them) are skipped.
        """
        P = self.kf.P
        used = np.flatnonzero(np.any(H != 0.0, axis=0))
        H_used = H[:, used]
        PHt = P[:, used] @ H_used.T
        S = H_used @ PHt[used] + R_meas
        S_inv = np.linalg.inv(S)
        if float(residual @ S_inv @ residual) > self._gate[residual.size] and \
                self.rejected_in_a_row[sensor] < self.config.max_consecutive_rejections:
            self.rejected_in_a_row[sensor] += 1
            return False
        self.rejected_in_a_row[sensor] = 0
        K = PHt @ S_inv
        P = P - K @ PHt.T
        self.kf.P = 0.5 * (P + P.T)
        self._inject(K @ residual)
        return True

    def _inject(self, dx: FloatArray) -> None:
        self.p = self.p + dx[POS]
        self.v = self.v + dx[VEL]
        self.R = orthonormalize(self.R @ exp_so3(dx[ATT]))
        self.gyro_bias = self.gyro_bias + dx[BG]
        self.accel_bias = self.accel_bias + dx[BA]
        self.wheel_scale = self.wheel_scale + dx[WS]
        self.clone_p = self.clone_p + dx[CPOS]
        self.clone_R = self.clone_R @ exp_so3(dx[CATT])
        if self.slots:
            slot_dx = dx[DIM:].reshape(self.slots, 6)
            self.slot_p = self.slot_p + slot_dx[:, :3]
            self.slot_R = self.slot_R @ exp_so3_many(slot_dx[:, 3:])
        self.kf.x = np.zeros((self.dim, 1))
