"""Camera geometry and the messages of the visual-odometry path: RGB-D frames and VO measurements.

Frames (REP-103/105): `base_link` is x forward, y left, z up; the camera's optical frame is z out of
the lens, x right, y down (image axes). A D435i colour stream with depth aligned to it shares one
pinhole model, so one set of intrinsics serves both images.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import ConfigError
from gprbot.messages import register_message

FloatArray = NDArray[np.float64]

# D435i RGB sensor (OV2740) at its native 1920×1080: fx ≈ fy ≈ 1380 px, 69.4° × 42.5° field of view
# (Intel D400 series datasheet, rev. 2020). Smaller modes are binned/cropped from it.
_NATIVE_WIDTH, _NATIVE_HEIGHT, _NATIVE_FOCAL_PX = 1920, 1080, 1380.0


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics (pixels) of an undistorted image."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def matrix(self) -> FloatArray:
        """The 3×3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


def d435i_intrinsics(width: int = 424, height: int = 240) -> CameraIntrinsics:
    """Intrinsics of a D435i colour mode: the native sensor scaled to `height`, cropped to `width`."""
    if width <= 0 or height <= 0:
        raise ConfigError(f"realsense.width/height: expected positive sizes, got {width}×{height}")
    scale = height / _NATIVE_HEIGHT
    if _NATIVE_WIDTH * scale + 0.5 < width:
        raise ConfigError(f"realsense.width: {width} px is wider than the D435i colour sensor allows at {height} px")
    focal = _NATIVE_FOCAL_PX * scale
    return CameraIntrinsics(width, height, focal, focal, (width - 1) / 2.0, (height - 1) / 2.0)


@dataclass(frozen=True)
class CameraMount:
    """Where the camera sits on the robot: optical centre in base_link (m), pitched down by pitch_deg."""

    position_m: tuple[float, float, float] = (0.20, 0.0, 0.30)
    pitch_down_deg: float = 60.0

    def rotation(self) -> FloatArray:
        """R_base_camera: columns are the optical x (right), y (down), z (forward-down) axes in base_link."""
        a = math.radians(self.pitch_down_deg)
        x_axis = np.array([0.0, -1.0, 0.0])
        z_axis = np.array([math.cos(a), 0.0, -math.sin(a)])
        y_axis = np.cross(z_axis, x_axis)
        return np.column_stack([x_axis, y_axis, z_axis])

    def transform(self) -> FloatArray:
        """T_base_camera as a 4×4 homogeneous matrix."""
        T = np.eye(4)
        T[:3, :3] = self.rotation()
        T[:3, 3] = self.position_m
        return T


@register_message
@dataclass(frozen=True)
class RgbdFrame:
    """One colour image (BGR uint8) with metric depth aligned to it (float32 m, 0 = no depth)."""

    t: float
    color: NDArray[np.uint8]
    depth_m: NDArray[np.float32]
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def intrinsics(self) -> CameraIntrinsics:
        """The pinhole model shared by the colour and the aligned depth image."""
        h, w = self.depth_m.shape
        return CameraIntrinsics(w, h, self.fx, self.fy, self.cx, self.cy)


VO_STATUSES = ("ok", "keyframe", "lost")


@register_message
@dataclass(frozen=True)
class VoMeasurement:
    """Visual odometry output in base_link terms.

    status "ok": the base moved by (rotation, translation) from t_ref (a keyframe) to t — the pose
    of base_link at t expressed in base_link at t_ref — with covariance (6×6, order: translation m,
    rotation rad as a right perturbation of `rotation`). `new_keyframe` says that the frame at t is
    the reference of the next measurements. status "keyframe": a new reference at t, no motion.
    status "lost": no usable motion at t (`reason` says why); motion restarts at the next keyframe.
    """

    t: float
    t_ref: float
    status: str
    rotation: NDArray[np.float64] = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    translation: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    covariance: NDArray[np.float64] = field(default_factory=lambda: np.eye(6))
    inliers: int = 0
    new_keyframe: bool = False
    reason: str = ""


@register_message
@dataclass(frozen=True)
class VoHealth:
    """VO as `status` and the run log show it (at host time t)."""

    t: float
    state: str  # "starting" (no frame yet), "tracking", "lost"
    frames: int
    dropped: int  # frames dropped from the queue because VO fell behind
    lost_frames: int
    measurements: int
    features: int  # corners of the current keyframe (0 when lost)
    tracked: int  # of those, tracked into the last frame
    inlier_ratio: float  # PnP inliers / tracked, last frame
    rate_hz: float
    latency_ms_median: float
    latency_ms_max: float
    cpu_s: float  # the VO thread's CPU time
    last_failure: str
