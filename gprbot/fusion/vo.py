"""RGB-D visual odometry: keyframe-relative camera motion, reported as base_link motion with covariance.

Every frame is tracked against the current keyframe (see vo_geometry). A measurement is emitted when
the keyframe is retired — the image has moved `keyframe_max_flow_px`, too few of its corners remain,
or it is older than `keyframe_max_age_s` — so consecutive measurements share no image noise and the
filter may treat them as independent. When tracking fails, the last good motion is emitted (stamped
with its own, earlier frame time: a late measurement the filter's reorder window absorbs) and VO says
"lost" until a frame with enough texture starts a new keyframe. It never guesses across a gap.
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
)
from gprbot.geometry import CameraMount
from gprbot.messages import RgbdFrame, VoMeasurement


class RgbdOdometry:
    """Frame-by-frame RGB-D odometry; `process` returns the measurements a frame completes."""

    def __init__(self, mount: CameraMount | None = None, config: VoConfig | None = None) -> None:
        self.config = config or VoConfig()
        mount = mount or CameraMount()
        self._R_bc = mount.rotation()
        self._t_bc = np.asarray(mount.position_m, dtype=np.float64)
        self.keyframe: Keyframe | None = None
        self.last_estimate: MotionEstimate | None = None
        self.last_failure = ""
        self.frames = 0
        self.lost_frames = 0

    def process(self, frame: RgbdFrame) -> list[VoMeasurement]:
        """Track one frame; the measurements (0, 1 or 2) it completes, in time order."""
        self.frames += 1
        gray = np.asarray(cv2.cvtColor(frame.color, cv2.COLOR_BGR2GRAY) if frame.color.ndim == 3 else frame.color,
                          dtype=np.uint8)
        if self.keyframe is None:
            return self._start_keyframe(frame, gray, was_tracking=False)
        kf = self.keyframe
        guess = (self.last_estimate.rvec, self.last_estimate.tvec) if self.last_estimate else None
        result = estimate_motion(kf, frame.t, gray, frame.intrinsics, self.config, guess)
        if isinstance(result, str):
            self.last_failure = result
            out = [self._measurement(self.last_estimate, kf.t, False)] if self.last_estimate else []
            return out + self._start_keyframe(frame, gray, was_tracking=True)
        c = self.config
        retire = (
            result.median_flow_px > c.keyframe_max_flow_px
            or result.inliers < c.keyframe_min_inlier_ratio * len(kf.points_2d)
            or frame.t - kf.t >= c.keyframe_max_age_s
        )
        if not retire:
            self.last_estimate = result
            return []
        started = self._start_keyframe(frame, gray, was_tracking=True, announce=False)
        closing = self._measurement(result, kf.t, self.keyframe is not None)
        return [closing, *started]

    def _start_keyframe(self, frame: RgbdFrame, gray: NDArray[np.uint8], was_tracking: bool,
                        announce: bool = True) -> list[VoMeasurement]:
        self.last_estimate = None
        self.keyframe = detect_keyframe(frame.t, gray, frame.depth_m, frame.intrinsics, self.config)
        if self.keyframe is not None:
            return [VoMeasurement(frame.t, frame.t, "keyframe", new_keyframe=True)] if announce else []
        self.lost_frames += 1
        if not was_tracking:
            return []
        return [VoMeasurement(frame.t, frame.t, "lost", reason=self.last_failure or "too few corners with depth")]

    def _measurement(self, estimate: MotionEstimate | None, t_ref: float, new_keyframe: bool) -> VoMeasurement:
        assert estimate is not None
        rotation, translation, covariance = self.base_motion(estimate)
        return VoMeasurement(estimate.t, t_ref, "ok", matrix_to_quat(rotation), translation, covariance,
                             estimate.inliers, new_keyframe)

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

    def _camera_to_base(self, params: FloatArray) -> tuple[FloatArray, FloatArray]:
        R_fk = exp_so3(params[:3])  # keyframe camera → frame camera
        R_kf, t_kf = R_fk.T, -R_fk.T @ params[3:]  # the frame camera's pose in the keyframe camera
        R = self._R_bc @ R_kf @ self._R_bc.T
        return R, self._R_bc @ t_kf + self._t_bc - R @ self._t_bc
