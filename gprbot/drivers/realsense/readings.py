"""What the RealSense source hands to its sink from librealsense's threads: IMU samples, RGB-D pairs
and events, as numpy data stamped by the device and by the host."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Intrinsics = tuple[float, float, float, float]  # fx, fy, cx, cy in pixels


@dataclass(frozen=True)
class MotionReading:
    """One gyro (rad/s) or accel (m/s²) sample, stamped by the device and on receipt by the host."""

    stream: str  # "gyro" or "accel"
    number: int
    device_ms: float
    domain: str
    host_s: float
    xyz: NDArray[np.float64]


@dataclass(frozen=True)
class RgbdReading:
    """A depth frame paired with the colour frame of the same instant, depth registered to colour."""

    depth_number: int
    color_number: int
    device_ms: float  # the depth frame's timestamp
    domain: str
    host_s: float
    color: NDArray[np.uint8]
    depth: NDArray[np.uint16]
    depth_scale: float
    intrinsics: Intrinsics  # of the colour camera, which the depth is registered to


@dataclass(frozen=True)
class SourceEvent:
    """Not data: the recording ended ("end"), the device was lost ("lost") or a frame failed ("error")."""

    kind: str
    detail: str = ""


Reading = MotionReading | RgbdReading | SourceEvent
Sink = Callable[[Reading], None]
