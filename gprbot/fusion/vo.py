"""RGB-D visual odometry: keyframe-relative camera motion, reported as base_link motion with covariance.

Every frame is tracked against the current keyframe (see vo_geometry). A measurement is emitted when
the keyframe is retired — the image has moved `keyframe_max_flow_px`, too few of its corners remain,
or it is older than `keyframe_max_age_s` — so consecutive measurements share no image noise and the
filter may treat them as independent. Frames are also tracked, now and then, against map keyframes
of floor seen before (fusion.vo_map): the motion from one is a measurement against that keyframe's
stored pose, which bounds the yaw's random walk across survey lines. When tracking fails, the last
good motion is emitted (stamped with its own, earlier frame time: a late measurement the filter's
reorder window absorbs) and VO says "lost" until a frame with enough texture starts a new keyframe.
It never guesses across a gap.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from gprbot.fusion.so3 import exp_so3, log_so3, matrix_to_quat
from gprbot.fusion.vo_geometry import (
    FloatArray,
    Keyframe,
    MotionEstimate,
    VoConfig,
    detect_keyframe,
    estimate_motion,
    warped_toward,
)
from gprbot.fusion.vo_map import KeyframeMap, MapConfig
from gprbot.geometry import CameraMount
from gprbot.messages import RgbdFrame, VoMeasurement


class RgbdOdometry:
    """Frame-by-frame RGB-D odometry; `process` returns the measurements a frame completes."""

    def __init__(self, mount: CameraMount | None = None, config: VoConfig | None = None,
                 map_config: MapConfig | None = None) -> None:
        self.config = config or VoConfig()
        self.map = KeyframeMap(map_config or MapConfig())
        mount = mount or CameraMount()
        self._R_bc = mount.rotation()
        self._t_bc = np.asarray(mount.position_m, dtype=np.float64)
        self.keyframe: Keyframe | None = None
        self.last_estimate: MotionEstimate | None = None
        self.last_failure = ""
        self.frames = 0
        self.lost_frames = 0
        # VO's own chained pose of base_link (where map keyframes lie, and the guess when one is tried):
        # at the current keyframe, at the last frame, and the last measured body velocity for gaps
        self._keyframe_pose = (np.zeros(3), np.eye(3))
        self._pose, self._pose_t = (np.zeros(3), np.eye(3)), float("nan")
        self._velocity, self._rate = np.zeros(3), np.zeros(3)
        self._new_slot = -1

    def process(self, frame: RgbdFrame) -> list[VoMeasurement]:
        """Track one frame; the measurements it completes, in time order."""
        self.frames += 1
        gray = np.asarray(cv2.cvtColor(frame.color, cv2.COLOR_BGR2GRAY) if frame.color.ndim == 3 else frame.color,
                          dtype=np.uint8)
        if self.keyframe is None:
            self._coast_to(frame.t)
            return self._start_keyframe(frame, gray, was_tracking=False)
        kf = self.keyframe
        guess = (self.last_estimate.rvec, self.last_estimate.tvec) if self.last_estimate else None
        result = estimate_motion(kf, frame.t, gray, frame.intrinsics, self.config, guess)
        if isinstance(result, str):
            self.last_failure = result
            out = [self._measurement(self.last_estimate, kf.t, False)] if self.last_estimate else []
            self._coast_to(frame.t)
            return out + self._start_keyframe(frame, gray, was_tracking=True)
        rotation, translation = self._track_to(result)
        c = self.config
        retire = (
            result.median_flow_px > c.keyframe_max_flow_px
            or result.inliers < c.keyframe_min_inlier_ratio * len(kf.points_2d)
            or frame.t - kf.t >= c.keyframe_max_age_s
        )
        if not retire:
            self.last_estimate = result
            return self._revisit(frame, gray)
        dt = max(result.t - kf.t, 1e-6)
        self._velocity, self._rate = translation / dt, log_so3(rotation) / dt
        started = self._start_keyframe(frame, gray, was_tracking=True, announce=False)
        closing = self._measurement(result, kf.t, self.keyframe is not None)
        return [closing, *started, *self._revisit(frame, gray)]

    def _track_to(self, estimate: MotionEstimate) -> tuple[FloatArray, FloatArray]:
        """VO's own pose at the frame (the keyframe's pose and the motion from it); that base_link motion."""
        rotation, translation = self._camera_to_base(np.concatenate([estimate.rvec, estimate.tvec]))
        p, R = self._keyframe_pose
        self._pose, self._pose_t = (p + R @ translation, R @ rotation), estimate.t
        self.map.moved_to(self._pose[0])
        return rotation, translation

    def _coast_to(self, t: float) -> None:
        """VO's own pose across frames it could not track: the last measured velocity, as VO has nothing else."""
        if not np.isnan(self._pose_t) and t > self._pose_t:
            p, R = self._pose
            dt = t - self._pose_t
            self._pose = (p + R @ self._velocity * dt, R @ exp_so3(self._rate * dt))
            self.map.moved_to(self._pose[0])
        self._pose_t = t

    def _revisit(self, frame: RgbdFrame, gray: NDArray[np.uint8]) -> list[VoMeasurement]:
        """The motion from a map keyframe of floor seen before, if one is within reach and is found again."""
        p, R = self._pose
        entry = self.map.candidate(frame.t, p)
        if entry is None:
            return []
        predicted_R, predicted_t = entry.rotation.T @ R, entry.rotation.T @ (p - entry.position)
        rvec, tvec = self._base_to_camera(predicted_R, predicted_t)
        start = warped_toward(entry.keyframe, rvec, tvec, frame.intrinsics)
        result = estimate_motion(start, frame.t, gray, frame.intrinsics, self.config, (rvec, tvec))
        if isinstance(result, str) or result.inliers < self.map.config.min_inliers:
            return []
        rotation, translation = self._camera_to_base(np.concatenate([result.rvec, result.tvec]))
        # A lock on the wrong patch of a repetitive floor lands far from where VO's own chain says it is
        # (which is good to a few cm between neighbouring lines); the filter's gate sees only its own view.
        off_m = float(np.linalg.norm(translation - predicted_t))
        off_rad = float(np.linalg.norm(log_so3(predicted_R.T @ rotation)))
        if off_m > self.map.config.max_surprise_m or off_rad > self.map.config.max_surprise_rad:
            return []
        self.map.found += 1
        return [self._measurement(result, entry.keyframe.t, False, revisit_slot=entry.slot)]

    def _start_keyframe(self, frame: RgbdFrame, gray: NDArray[np.uint8], was_tracking: bool,
                        announce: bool = True) -> list[VoMeasurement]:
        self.last_estimate = None
        self.keyframe = detect_keyframe(frame.t, gray, frame.depth_m, frame.intrinsics, self.config)
        if self.keyframe is not None:
            self._keyframe_pose = self._pose
            self._new_slot = self.map.offer(self.keyframe, *self._pose)
            if not announce:
                return []
            return [VoMeasurement(frame.t, frame.t, "keyframe", new_keyframe=True, map_slot=self._new_slot)]
        self.lost_frames += 1
        if not was_tracking:
            return []
        return [VoMeasurement(frame.t, frame.t, "lost", reason=self.last_failure or "too few corners with depth")]

    def _measurement(self, estimate: MotionEstimate | None, t_ref: float, new_keyframe: bool,
                     revisit_slot: int = -1) -> VoMeasurement:
        assert estimate is not None
        rotation, translation, covariance = self.base_motion(estimate)
        return VoMeasurement(estimate.t, t_ref, "ok", matrix_to_quat(rotation), translation, covariance,
                             estimate.inliers, new_keyframe, map_slot=self._new_slot if new_keyframe else -1,
                             revisit_slot=revisit_slot)

    def base_motion(self, estimate: MotionEstimate) -> tuple[FloatArray, FloatArray, FloatArray]:
        """base_link at the frame expressed in base_link at the keyframe: R, t and their 6×6 covariance."""
        params = np.concatenate([estimate.rvec, estimate.tvec])
        R0, t0 = self._camera_to_base(params)
        J = np.empty((6, 6))
        step = 1e-6
        for i in range(6):
            d = np.zeros(6)
            d[i] = step
            Rp, tp = self._camera_to_base(params + d)
            Rm, tm = self._camera_to_base(params - d)
            J[:3, i] = (tp - tm) / (2 * step)
            J[3:, i] = (log_so3(R0.T @ Rp) - log_so3(R0.T @ Rm)) / (2 * step)
        return R0, t0, J @ estimate.covariance @ J.T

    def _base_to_camera(self, rotation: FloatArray, translation: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The inverse of `_camera_to_base`: a base_link motion as the camera's (rvec, tvec)."""
        R_kf = self._R_bc.T @ rotation @ self._R_bc
        t_kf = self._R_bc.T @ (translation - self._t_bc + rotation @ self._t_bc)
        R_fk = R_kf.T
        return log_so3(R_fk), -R_fk @ t_kf

    def _camera_to_base(self, params: FloatArray) -> tuple[FloatArray, FloatArray]:
        R_fk = exp_so3(params[:3])  # keyframe camera → frame camera
        R_kf, t_kf = R_fk.T, -R_fk.T @ params[3:]  # the frame camera's pose in the keyframe camera
        R = self._R_bc @ R_kf @ self._R_bc.T
        return R, self._R_bc @ t_kf + self._t_bc - R @ self._t_bc
