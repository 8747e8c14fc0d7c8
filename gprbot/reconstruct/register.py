"""Registration of per-line cross-section masks in 3D, and resampling of the registered cloud.

A survey line's cross-section mask is an image in (depth, along-track column). Each column belongs to
one antenna position (the robot base pose ⊕ the antenna lever arm), so every white pixel becomes a
site-frame point: the column's horizontal position and the pixel's depth below the surface.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import InterpretationError

# Duplicated points (when a cloud has fewer points than asked for) are moved by this much so that no two
# points coincide; far below any mask pixel (≥ 2 mm), so it adds no visible noise.
DUPLICATE_JITTER_M = 2e-4


@dataclass(frozen=True)
class SliceCloud:
    """The mask pixels of one survey line in 3D (site frame), and the line's unit along-track vector.

    `pixel_pitch_m` is the mask's (along-track, depth) pixel size when known; blob finding uses it.
    """

    line: int
    points: NDArray[np.float64]
    direction: NDArray[np.float64]
    pixel_pitch_m: tuple[float, float] | None = None
    pose_std_m: float = 0.0  # RMS 1σ of the line's antenna positions (from the pose filter); 0: unknown
    track_xy: NDArray[np.float64] | None = None  # (2, 2): where the line started and ended in plan; None: unknown


def line_direction(column_positions: NDArray[np.float64]) -> NDArray[np.float64]:
    """The unit horizontal along-track vector of a line: principal axis of its positions, first → last."""
    xy = np.asarray(column_positions, dtype=np.float64)[:, :2]
    if len(xy) < 2:
        raise InterpretationError("a survey line needs at least 2 antenna positions to give its direction")
    centred = xy - xy.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    direction = vt[0]
    if float(np.dot(xy[-1] - xy[0], direction)) < 0.0:
        direction = -direction
    if float(np.ptp(centred @ direction)) < 1e-6:
        raise InterpretationError(
            "the survey line's antenna positions do not move along-track; check the poses of this line"
        )
    return np.asarray(direction / np.linalg.norm(direction), dtype=np.float64)


def register_slice(
    line: int,
    mask: NDArray[np.bool_],
    z_m: NDArray[np.float64],
    column_positions: NDArray[np.float64],
    pose_std_m: float = 0.0,
) -> SliceCloud:
    """Register a cross-section mask in 3D: pixel (iz, ix) → (column x, column y, −z_m[iz])."""
    mask = np.asarray(mask, dtype=bool)
    z_m = np.asarray(z_m, dtype=np.float64)
    columns = np.asarray(column_positions, dtype=np.float64)
    if mask.ndim != 2:
        raise InterpretationError(f"line {line}: the cross-section mask must be 2-D (nz, nx), got {mask.shape}")
    nz, nx = mask.shape
    if z_m.shape != (nz,) or columns.shape != (nx, 3):
        raise InterpretationError(
            f"line {line}: mask {mask.shape} needs z_m ({nz},) and column positions ({nx}, 3), "
            f"got {z_m.shape} and {columns.shape}"
        )
    if not (np.all(np.isfinite(z_m)) and np.all(np.isfinite(columns))):
        raise InterpretationError(f"line {line}: depths or antenna positions are not finite")
    direction = line_direction(columns)
    iz, ix = np.nonzero(mask)
    # Depth is taken along the site vertical, not along the antenna's tilted boresight: the antenna is
    # ground-coupled (it rides 1–5 cm above the surface and z_m is already measured from the surface), and
    # the robot tilts < 1°, which moves a pixel 0.6 m deep by < 1 cm sideways — below a mask pixel.
    points = np.column_stack([columns[ix, 0], columns[ix, 1], -z_m[iz]])
    pitch_along = float(np.median(np.linalg.norm(np.diff(columns[:, :2], axis=0), axis=1)))
    pitch_depth = float(np.median(np.abs(np.diff(z_m)))) if nz > 1 else 0.0
    return SliceCloud(line=line, points=points, direction=direction, pixel_pitch_m=(pitch_along, pitch_depth),
                      pose_std_m=pose_std_m, track_xy=columns[[0, -1], :2].copy())


def farthest_point_indices(points: NDArray[np.float64], n: int, rng: np.random.Generator) -> NDArray[np.intp]:
    """Indices of n points chosen by farthest-point sampling from a random start (n ≤ len(points))."""
    chosen = np.empty(n, dtype=np.intp)
    chosen[0] = rng.integers(len(points))
    nearest = np.sum((points - points[chosen[0]]) ** 2, axis=1)
    for k in range(1, n):
        chosen[k] = int(np.argmax(nearest))
        nearest = np.minimum(nearest, np.sum((points - points[chosen[k]]) ** 2, axis=1))
    return chosen


def resample_cloud(
    points: NDArray[np.float64],
    n: int,
    rng: np.random.Generator,
    *,
    method: Literal["uniform", "farthest"] = "uniform",
) -> NDArray[np.float64]:
    """Exactly n points from a cloud: a subset when it has more, else all of it plus jittered repeats.

    "uniform" keeps the cloud's density (what GPRNet saw in training); "farthest" spreads points evenly
    over the shape but favours isolated noise points.
    """
    pts = np.asarray(points, dtype=np.float64)
    if n < 1:
        raise ValueError(f"resample_cloud: n must be ≥ 1, got {n}")
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InterpretationError(f"a point cloud must be (M, 3), got {pts.shape}")
    if len(pts) == 0:
        raise InterpretationError(
            "cannot resample an empty point cloud: no survey line has any mask pixel; "
            "check the interpretation (mask threshold) or whether the survey crossed any pipe"
        )
    if len(pts) >= n:
        if method == "farthest":
            return pts[farthest_point_indices(pts, n, rng)]
        return pts[rng.choice(len(pts), size=n, replace=False)]
    extra = rng.integers(len(pts), size=n - len(pts))
    repeats = pts[extra] + rng.normal(scale=DUPLICATE_JITTER_M, size=(len(extra), 3))
    out = np.concatenate([pts, repeats])
    return out[rng.permutation(n)]
