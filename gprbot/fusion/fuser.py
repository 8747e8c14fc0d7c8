"""The pose estimator's front end: time ordering, routing of sensor messages, Pose output, pose_at(t).

Late and out-of-order messages are handled by a fixed-latency reorder buffer: every message waits
until the newest timestamp seen is `reorder_window_s` past it, and messages are then processed in
timestamp order (IMU before wheels before VO at equal times). Anything that arrives later than the
window is dropped and counted — it would otherwise need the past re-filtered. The price is that
output poses trail the newest sensor data by the window (0.1 s by default); traces are tagged after
the fact through `pose_at`, so this costs the survey nothing. Pure: time comes from the messages.

The IMU is the filter's backbone and is never let fall behind the window: when its samples lag
(a stalled event loop delivers the camera's backlog after fresher wheel readings), nothing later
than the newest IMU sample of the two streams (gyro and accelerometer, delivered apart: a gyro
backlog ahead of the accelerometer's dropped 1,209 accelerometer samples in one daemon survey) is
released until the IMU catches up — for at most `max_imu_wait_s`, so
that a dead IMU does not freeze the poses. Wheel readings are held for the same way, for at most
`max_wheel_wait_s`: a reading is stamped when its requests left and submitted once six replies are
in, so on a busy loop it arrives after IMU samples more than the window newer (in a 10-line daemon
survey on a quiet machine, 1,416 late drops beside 12,214 wheel updates; 1 with the wait).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.config import FusionConfig, MotorsConfig
from gprbot.errors import GprbotError
from gprbot.fusion.ekf import ErrorStateEkf
from gprbot.fusion.interpolate import interpolate_poses
from gprbot.fusion.pose_history import PoseHistory
from gprbot.fusion.so3 import matrix_to_quat, yaw_of
from gprbot.messages import ImuSample, Pose, VoMeasurement, WheelSpeeds
from gprbot.motion.kinematics import KiwiKinematics

SensorMessage = ImuSample | WheelSpeeds | VoMeasurement
_PRIORITY = {ImuSample: 0, WheelSpeeds: 1, VoMeasurement: 2}


@dataclass
class FusionStats:
    """What the filter did with its input (for health reports and tests)."""

    imu: int = 0
    wheel_updates: int = 0
    wheel_rejected: int = 0
    vo_updates: int = 0
    vo_rejected: int = 0
    vo_skipped: int = 0
    revisit_updates: int = 0  # of vo_*, motions from a map keyframe seen again
    revisit_rejected: int = 0
    vo_lost: int = 0
    late_dropped: int = 0
    vo_late_dropped: int = 0  # of late_dropped, VO measurements (VO slower than the reorder window)
    imu_late_dropped: int = 0  # of late_dropped, IMU samples
    wheel_late_dropped: int = 0  # of late_dropped, wheel readings


class PoseFuser:
    """Feed sensor messages with `push`; get base_link poses in odom at `output_rate_hz`."""

    def __init__(self, config: FusionConfig | None = None, motors: MotorsConfig | None = None,
                 initial_position: tuple[float, float, float] = (0.0, 0.0, 0.0), initial_yaw_rad: float = 0.0) -> None:
        self.config = config or FusionConfig()
        self.ekf = ErrorStateEkf(self.config, KiwiKinematics.from_config(motors or MotorsConfig()))
        self.stats = FusionStats()
        self._initial = (np.asarray(initial_position, dtype=np.float64), initial_yaw_rad)
        self._heap: list[tuple[float, int, int, SensorMessage]] = []
        self._next_seq = 0  # ties in time and priority keep arrival order
        self._newest = -math.inf
        self._newest_gyro = -math.inf  # the D435i's gyro and accelerometer are two streams, delivered apart
        self._newest_accel = -math.inf
        self._newest_wheel = -math.inf
        self._released = -math.inf
        self._init_gyro: list[NDArray[np.float64]] = []
        self._init_accel: list[NDArray[np.float64]] = []
        self._init_start = math.nan
        self._next_tick = math.nan
        self.history = PoseHistory(int(self.config.history_s * self.config.output_rate_hz))

    def push(self, message: SensorMessage) -> list[Pose]:
        """Queue one message; the output poses that became final."""
        key = message.t - self.config.wheel_speed_delay_s if isinstance(message, WheelSpeeds) else message.t
        # a late one too: its stream lags, so wait for the next
        if isinstance(message, WheelSpeeds):
            self._newest_wheel = max(self._newest_wheel, key)
        elif isinstance(message, ImuSample):
            if message.gyro is not None:
                self._newest_gyro = max(self._newest_gyro, key)
            if message.accel is not None:
                self._newest_accel = max(self._newest_accel, key)
        if key < self._released:
            self.stats.late_dropped += 1
            self.stats.vo_late_dropped += isinstance(message, VoMeasurement)
            self.stats.imu_late_dropped += isinstance(message, ImuSample)
            self.stats.wheel_late_dropped += isinstance(message, WheelSpeeds)
            return []
        heapq.heappush(self._heap, (key, _PRIORITY[type(message)], self._next_seq, message))
        self._next_seq += 1
        self._newest = max(self._newest, key)
        return self._release(self._horizon())

    @property
    def _newest_imu(self) -> float:
        """The newest time both IMU streams have reached (the one stream, if only one was ever seen)."""
        seen = [t for t in (self._newest_gyro, self._newest_accel) if t > -math.inf]
        return min(seen) if seen else -math.inf

    def _horizon(self) -> float:
        """How far the buffer may be released: the window behind the newest message, held back to the
        newest IMU sample and wheel reading while they lag (each for at most its wait)."""
        c = self.config
        horizon = self._newest - c.reorder_window_s
        newest_imu = self._newest_imu
        if self._newest - newest_imu <= c.max_imu_wait_s:
            horizon = min(horizon, newest_imu)
        if self._newest - self._newest_wheel <= c.max_wheel_wait_s:
            horizon = min(horizon, self._newest_wheel)
        return horizon

    def flush(self) -> list[Pose]:
        """Process everything still queued (end of a run)."""
        return self._release(math.inf)

    def pose_at(self, t: NDArray[np.float64] | float) -> list[Pose]:
        """Interpolated poses at times within the kept output history."""
        times = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if len(self.history) < 2:
            raise GprbotError("no pose history yet: the filter needs IMU data (and a moment at rest) first")
        poses = self.history.around(float(times.min()), float(times.max()))
        if len(poses) < 2:  # all of them before the first pose or after the last
            first, last = self.history.span()
            raise GprbotError(f"cannot tag data at t=[{times.min():.3f}, {times.max():.3f}] s: poses cover "
                              f"[{first:.3f}, {last:.3f}] s only")
        return interpolate_poses(poses, times)

    def _release(self, horizon: float) -> list[Pose]:
        out: list[Pose] = []
        while self._heap and self._heap[0][0] <= horizon:
            key, _, _, message = heapq.heappop(self._heap)
            self._released = key
            out.extend(self._process(key, message))
        return out

    def _process(self, t: float, message: SensorMessage) -> list[Pose]:
        ekf = self.ekf
        if not ekf.initialized:
            self._collect_initial(message)
            return []
        out = self._emit_ticks(t)
        if isinstance(message, ImuSample):
            self.stats.imu += 1
            ekf.add_imu(t, message.gyro, message.accel)
            return out
        ekf.propagate_to(t)
        if isinstance(message, WheelSpeeds):
            accepted = ekf.update_wheels(message.speeds, message.sample_offsets_s)
            self.stats.wheel_updates += accepted
            self.stats.wheel_rejected += not accepted
        else:
            self._process_vo(message)
        return out

    def _process_vo(self, m: VoMeasurement) -> None:
        if m.status == "ok":
            result = self.ekf.update_vo(m)
            self.stats.vo_updates += result == "applied"
            self.stats.vo_rejected += result == "rejected"
            self.stats.vo_skipped += result == "skipped"
            if m.revisit_slot >= 0:
                self.stats.revisit_updates += result == "applied"
                self.stats.revisit_rejected += result == "rejected"
        elif m.status == "lost":
            self.stats.vo_lost += 1
        if m.new_keyframe:
            self.ekf.clone()
            if m.map_slot >= 0:
                self.ekf.store_in_slot(m.map_slot)

    def _emit_ticks(self, t: float) -> list[Pose]:
        """The output poses due up to t (extrapolated from the state, which trails by < one IMU step)."""
        ekf, out = self.ekf, list[Pose]()
        if self._next_tick > t:
            return out
        period = 1.0 / self.config.output_rate_hz
        position_std, yaw_std = ekf.horizontal_std()  # an eigen-solve: once per due tick, not per message
        while self._next_tick <= t:
            position, attitude = ekf.extrapolate(self._next_tick)
            out.append(Pose(self._next_tick, position, matrix_to_quat(attitude), position_std, yaw_std))
            self._next_tick = round((self._next_tick + period) / period) * period
        self.history.extend(out)
        return out

    def _collect_initial(self, message: SensorMessage) -> None:
        if not isinstance(message, ImuSample):
            return
        if math.isnan(self._init_start):
            self._init_start = message.t
        if message.gyro is not None:
            self._init_gyro.append(np.asarray(message.gyro, dtype=np.float64))
        if message.accel is not None:
            self._init_accel.append(np.asarray(message.accel, dtype=np.float64))
        if message.t - self._init_start >= self.config.init_duration_s and self._init_gyro and self._init_accel:
            position, yaw = self._initial
            gyro_bias = np.mean(self._init_gyro, axis=0) if self.config.gyro_bias_from_rest else np.zeros(3)
            self.ekf.initialize(message.t, np.mean(self._init_accel, axis=0), gyro_bias, position, yaw)
            period = 1.0 / self.config.output_rate_hz
            self._next_tick = math.ceil(message.t / period - 1e-9) * period

    @property
    def yaw_rad(self) -> float:
        """Current heading estimate (rad) in odom."""
        return yaw_of(self.ekf.R)
