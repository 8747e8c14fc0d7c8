"""Simulated D435i RGB-D camera looking down at the floor: colour and aligned metric depth at 30 fps.

Each pixel's ray (the D435i pinhole model) is cut with the floor plane z = 0; the cut point picks the
floor texture (cv2.remap) and its distance along the optical axis is the depth. On top: motion blur
over the exposure (a line kernel along the image motion), sensor noise, and D435i-like depth noise —
σ_z = z² · σ_d / (f · b) with subpixel disparity noise σ_d 0.08 px, baseline b 50 mm and the depth
imager's focal length (Intel's depth-accuracy formula), quantised to the 1 mm depth unit, with holes.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from gprbot.geometry import CameraMount, d435i_intrinsics
from gprbot.messages import RgbdFrame
from gprbot.sim.floor_texture import FloorSpec, FloorTexture
from gprbot.sim.motion_truth import GroundTruth

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class CameraModel:
    """Image size, timing and noise of the simulated camera."""

    width: int = 424
    height: int = 240
    fps: float = 30.0
    exposure_s: float = 0.008
    pixel_noise_dn: float = 2.0
    depth_focal_px: float = 425.0  # the depth imager at 848×480
    depth_baseline_m: float = 0.050
    disparity_noise_px: float = 0.08
    depth_hole_fraction: float = 0.005
    min_depth_m: float = 0.11
    mount: CameraMount = field(default_factory=CameraMount)


class FloorCamera:
    """Renders RgbdFrame messages of the floor from base poses (or straight from a ground truth)."""

    def __init__(self, floor: FloorSpec | None = None, model: CameraModel | None = None, seed: int = 0) -> None:
        self.model = model or CameraModel()
        self.floor = FloorTexture(floor or FloorSpec())
        self.intrinsics = d435i_intrinsics(self.model.width, self.model.height)
        k = self.intrinsics
        u, v = np.meshgrid(np.arange(k.width, dtype=np.float32), np.arange(k.height, dtype=np.float32))
        self._rays = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u)]).reshape(3, -1)
        self._R_bc = self.model.mount.rotation()
        self._t_bc = np.asarray(self.model.mount.position_m, dtype=np.float64)
        self._rng = np.random.default_rng(seed + 49979687)
        shape = (2 * k.height, 2 * k.width)
        self._pixel_noise = self._rng.normal(0.0, self.model.pixel_noise_dn, shape).astype(np.float32)
        self._depth_noise = self._rng.standard_normal(shape).astype(np.float32)
        self._holes = self._rng.random(shape) < self.model.depth_hole_fraction

    def frames(
        self, truth: GroundTruth, t_start: float | None = None, t_end: float | None = None
    ) -> Iterator[RgbdFrame]:
        """Frames at the camera rate over [t_start, t_end) of the trajectory."""
        t0 = truth.t_start if t_start is None else t_start
        t1 = truth.t_end - self.model.exposure_s if t_end is None else t_end
        for t in np.arange(t0, t1, 1.0 / self.model.fps):
            yield self.render_truth(float(t), truth)

    def render_truth(self, t: float, truth: GroundTruth) -> RgbdFrame:
        """The frame exposed around t, with the blur of the motion during the exposure."""
        half = 0.5 * self.model.exposure_s
        times = np.array([t - half, t, t + half])
        R, p = truth.rotation(times), truth.position(times)
        return self.render_moving(t, (R[0], p[0]), (R[1], p[1]), (R[2], p[2]))

    def render_moving(self, t: float, start: tuple[FloatArray, FloatArray], middle: tuple[FloatArray, FloatArray],
                      end: tuple[FloatArray, FloatArray]) -> RgbdFrame:
        """The frame exposed around t from the base poses (R, p) at the exposure's start, middle and end."""
        return self.render(t, middle[0], middle[1], self._image_motion(start[0], start[1], end[0], end[1]))

    def render(self, t: float, R_odom_base: FloatArray, p_odom_base: FloatArray,
               blur_px: tuple[float, float] = (0.0, 0.0)) -> RgbdFrame:
        """The frame seen from a base pose (R, p in odom), smeared by blur_px over the exposure."""
        k = self.intrinsics
        R_wc = (R_odom_base @ self._R_bc).astype(np.float32)
        origin = (p_odom_base + R_odom_base @ self._t_bc).astype(np.float32)
        dirs = R_wc @ self._rays
        with np.errstate(divide="ignore"):
            depth = np.where(dirs[2] < -1e-6, -origin[2] / dirs[2], 0.0).astype(np.float32)
        col, row = self.floor.pixel_coordinates(origin[0] + depth * dirs[0], origin[1] + depth * dirs[1])
        gray: NDArray[np.float32] = cv2.remap(
            self.floor.image, col.reshape(k.height, k.width), row.reshape(k.height, k.width), cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_WRAP,
        ).astype(np.float32)
        kernel = _line_kernel(*blur_px)
        if kernel is not None:
            gray = np.asarray(cv2.filter2D(gray, -1, kernel, borderType=cv2.BORDER_REPLICATE), dtype=np.float32)
        oy, ox = int(self._rng.integers(k.height)), int(self._rng.integers(k.width))
        gray += self._pixel_noise[oy:oy + k.height, ox:ox + k.width]
        color = np.asarray(cv2.cvtColor(np.clip(gray, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR), dtype=np.uint8)
        return RgbdFrame(t, color, self._noisy_depth(depth.reshape(k.height, k.width)), k.fx, k.fy, k.cx, k.cy)

    def _noisy_depth(self, depth: NDArray[np.float32]) -> NDArray[np.float32]:
        m, k = self.model, self.intrinsics
        oy, ox = int(self._rng.integers(k.height)), int(self._rng.integers(k.width))
        gain = np.float32(1000.0 * m.disparity_noise_px / (m.depth_focal_px * m.depth_baseline_m))
        noise = self._depth_noise[oy:oy + k.height, ox:ox + k.width]
        noisy_mm = depth * np.float32(1000.0) + depth * depth * gain * noise
        noisy = np.rint(noisy_mm) * np.float32(0.001)  # the D435i's default depth unit is 1 mm
        holes = self._holes[oy:oy + k.height, ox:ox + k.width] | (depth < m.min_depth_m)
        noisy[holes] = 0.0
        return noisy

    def _image_motion(self, R0: FloatArray, p0: FloatArray, R1: FloatArray, p1: FloatArray) -> tuple[float, float]:
        """Pixel displacement of the floor point at the image centre between two base poses."""
        k = self.intrinsics
        R_wc0, o0 = R0 @ self._R_bc, p0 + R0 @ self._t_bc
        ray = R_wc0 @ np.array([0.0, 0.0, 1.0])
        point = o0 + (-o0[2] / ray[2]) * ray
        R_wc1, o1 = R1 @ self._R_bc, p1 + R1 @ self._t_bc
        x, y, z = R_wc1.T @ (point - o1)
        return float(k.fx * x / z), float(k.fy * y / z)  # the point sat at the principal point at pose 0


def _line_kernel(dx: float, dy: float) -> NDArray[np.float32] | None:
    """A normalised kernel that smears an image uniformly along (dx, dy) pixels; None below half a pixel."""
    length = math.hypot(dx, dy)
    if length < 0.5:
        return None
    half = math.ceil(max(abs(dx), abs(dy)) / 2.0) + 1
    kernel = np.zeros((2 * half + 1, 2 * half + 1), dtype=np.float32)
    for s in np.linspace(-0.5, 0.5, max(3, math.ceil(4 * length))):
        x, y = half + s * dx, half + s * dy
        x0, y0 = math.floor(x), math.floor(y)
        fx, fy = x - x0, y - y0
        kernel[y0, x0] += (1 - fx) * (1 - fy)
        kernel[y0, x0 + 1] += fx * (1 - fy)
        kernel[y0 + 1, x0] += (1 - fx) * fy
        kernel[y0 + 1, x0 + 1] += fx * fy
    return np.asarray(kernel / kernel.sum(), dtype=np.float32)
