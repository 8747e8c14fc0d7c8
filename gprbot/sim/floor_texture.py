"""A procedural concrete floor for the simulated camera: one periodic grey-level tile over the odom x-y plane.

The tile is 1/f ("pink") noise made by spectral synthesis — periodic by construction, so it wraps
without seams — band-limited at 4 mm so that the camera (≈1–2 mm per pixel) does not alias it, with
aggregate specks on top. Rectangles of the floor can be made texture-poor (smooth paint), where
visual odometry finds no corners and loses tracking, as it does on a real floor.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import scipy.fft
from numpy.typing import NDArray

Rect = tuple[float, float, float, float]  # x0, y0, x1, y1 in metres (odom)


@dataclass(frozen=True)
class FloorSpec:
    """Size, resolution and texture-poor patches of the floor tile."""

    size_px: tuple[int, int] = (3072, 2048)  # along x, along y
    resolution_m: float = 0.001
    origin_m: tuple[float, float] = (-0.6, -0.6)  # odom position of the tile's pixel (0, 0)
    smooth_patches_m: tuple[Rect, ...] = ((0.95, -0.5, 1.65, 0.45),)
    patch_contrast: float = 0.03
    plain: bool = False  # a uniform floor without any texture (a VO failure case)
    seed: int = 0


class FloorTexture:
    """The floor tile (uint8, rows along y, columns along x) and how odom metres map to its pixels."""

    def __init__(self, spec: FloorSpec) -> None:
        self.spec = spec
        self.image: NDArray[np.uint8] = _cached_tile(spec)

    def pixel_coordinates(self, x_m: NDArray[np.float32], y_m: NDArray[np.float32]) -> tuple[NDArray[np.float32], ...]:
        """Tile column and row (float) of odom points; the tile repeats beyond its size."""
        s = self.spec
        return (x_m - np.float32(s.origin_m[0])) / np.float32(s.resolution_m), (
            y_m - np.float32(s.origin_m[1])
        ) / np.float32(s.resolution_m)


_TILES: dict[FloorSpec, NDArray[np.uint8]] = {}


def _cached_tile(spec: FloorSpec) -> NDArray[np.uint8]:
    if spec not in _TILES:
        _TILES.clear()  # keep one tile in memory (a full tile is 6 MB)
        _TILES[spec] = _make_tile(spec)
    return _TILES[spec]


def _make_tile(spec: FloorSpec) -> NDArray[np.uint8]:
    nx, ny = spec.size_px
    if spec.plain:
        return np.full((ny, nx), 128, dtype=np.uint8)
    rng = np.random.default_rng(spec.seed + 32452843)
    spectrum = scipy.fft.rfft2(rng.standard_normal((ny, nx)).astype(np.float32))
    fy = scipy.fft.fftfreq(ny, spec.resolution_m)[:, None]
    fx = scipy.fft.rfftfreq(nx, spec.resolution_m)[None, :]
    f = np.sqrt(fx**2 + fy**2)
    cutoff = 1.0 / 0.004  # cycles per metre: nothing finer than 4 mm
    gain = np.exp(-0.5 * (f / cutoff) ** 2) / np.maximum(f, 5.0)
    field = scipy.fft.irfft2(spectrum * gain.astype(np.float32), s=(ny, nx))
    image = 128.0 + 38.0 * (field - field.mean()) / field.std()
    specks = int(3000 * nx * ny * spec.resolution_m**2)  # aggregate: ~3000 grains per m²
    canvas = np.zeros((ny, nx), dtype=np.float32)
    for x, y, r, v in zip(
        rng.integers(0, nx, specks), rng.integers(0, ny, specks), rng.integers(2, 5, specks),
        rng.choice([-60.0, 50.0], specks), strict=True,
    ):
        cv2.circle(canvas, (int(x), int(y)), int(r), float(v), -1, lineType=cv2.LINE_AA)
    image += cv2.GaussianBlur(canvas, (0, 0), 0.8)
    for x0, y0, x1, y1 in spec.smooth_patches_m:
        weight = _patch_weight(spec, (x0, y0, x1, y1))
        mean = cv2.GaussianBlur(image, (0, 0), 30.0)
        smooth = 150.0 + spec.patch_contrast * (image - mean)
        image = image * (1.0 - weight) + smooth * weight
    return np.asarray(np.clip(image, 0, 255), dtype=np.uint8)


def _patch_weight(spec: FloorSpec, rect: Rect) -> NDArray[np.float32]:
    """1 inside the rectangle, 0 outside, with a 15 mm soft edge (paint is not a step)."""
    nx, ny = spec.size_px
    x = spec.origin_m[0] + np.arange(nx) * spec.resolution_m
    y = spec.origin_m[1] + np.arange(ny) * spec.resolution_m
    edge = 0.015
    wx = np.clip(np.minimum(x - rect[0], rect[2] - x) / edge + 0.5, 0.0, 1.0)
    wy = np.clip(np.minimum(y - rect[1], rect[3] - y) / edge + 0.5, 0.0, 1.0)
    return np.asarray(wy[:, None] * wx[None, :], dtype=np.float32)
