"""The robot's and the pipes' geometry, once: lines, segments and polylines, the camera's mount and intrinsics.

Frames (REP-103/105): `base_link` is x forward, y left, z up; the camera's optical frame is z out of
the lens, x right, y down (image axes). A D435i colour stream with depth aligned to it shares one
pinhole model, so one set of intrinsics serves both images.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from gprbot.errors import ConfigError, InterpretationError
from gprbot.messages import CameraIntrinsics, Pose

_EPS = 1e-12


def fit_line(points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares 3-D line through points (≥ 2): (centroid, unit direction)."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    return centroid, np.asarray(vt[0], dtype=np.float64)


def distance_to_line(
    points: NDArray[np.float64], origin: NDArray[np.float64], direction: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Perpendicular distances of points (M, 3) to an infinite line (origin, unit direction)."""
    rel = points - origin
    return np.asarray(np.linalg.norm(rel - np.outer(rel @ direction, direction), axis=1), dtype=np.float64)


def distance_to_polyline(points: NDArray[np.float64], polyline: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distances of points (M, 3) to the nearest point of a polyline (K, 3), segments clamped at ends."""
    points = np.atleast_2d(points)
    if len(polyline) == 1:
        return np.asarray(np.linalg.norm(points - polyline[0], axis=1), dtype=np.float64)
    best = np.full(len(points), np.inf)
    for a, b in itertools.pairwise(polyline):
        ab = b - a
        t = np.clip((points - a) @ ab / max(float(ab @ ab), _EPS), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + np.outer(t, ab)), axis=1))
    return best


def closest_points_of_lines(
    p: NDArray[np.float64], u: NDArray[np.float64], q: NDArray[np.float64], v: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Closest points of two infinite lines p + s·u and q + t·v; None when they are parallel."""
    w = p - q
    a, b, c = float(u @ u), float(u @ v), float(v @ v)
    d, e = float(u @ w), float(v @ w)
    denom = a * c - b * b
    if denom < 1e-9 * a * c:
        return None
    s = (b * e - c * d) / denom
    t = (a * e - b * d) / denom
    return p + s * u, q + t * v


def closest_points_of_segments(
    p0: NDArray[np.float64], p1: NDArray[np.float64], q0: NDArray[np.float64], q1: NDArray[np.float64]
) -> tuple[float, float, float]:
    """Closest approach of segments p0p1 and q0q1: (s, t, distance), s and t in [0, 1]."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = float(d1 @ d1), float(d2 @ d2), float(d2 @ r)
    if a <= _EPS and e <= _EPS:
        return 0.0, 0.0, float(np.linalg.norm(r))
    if a <= _EPS:
        s, t = 0.0, float(np.clip(f / e, 0.0, 1.0))
    else:
        c = float(d1 @ r)
        if e <= _EPS:
            s, t = float(np.clip(-c / a, 0.0, 1.0)), 0.0
        else:
            b = float(d1 @ d2)
            denom = a * e - b * b
            s = float(np.clip((b * f - c * e) / denom, 0.0, 1.0)) if denom > _EPS else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                s, t = float(np.clip(-c / a, 0.0, 1.0)), 0.0
            elif t > 1.0:
                s, t = float(np.clip((b - c) / a, 0.0, 1.0)), 1.0
    gap = (p0 + s * d1) - (q0 + t * d2)
    return s, t, float(np.linalg.norm(gap))


def polyline_length(polyline: NDArray[np.float64]) -> float:
    """Total length of a polyline (K, 3)."""
    return float(np.sum(np.linalg.norm(np.diff(polyline, axis=0), axis=1)))


def densify(polyline: NDArray[np.float64], step_m: float) -> NDArray[np.float64]:
    """Points along a polyline at most step_m apart, its vertices included."""
    out = [polyline[:1]]
    for a, b in itertools.pairwise(polyline):
        count = max(1, int(np.ceil(np.linalg.norm(b - a) / step_m)))
        t = np.linspace(0.0, 1.0, count + 1)[1:]
        out.append(a + np.outer(t, b - a))
    return np.concatenate(out)


def drop_repeated_vertices(polyline: NDArray[np.float64], tolerance_m: float = 1e-3) -> NDArray[np.float64]:
    """The polyline without vertices within tolerance_m of the previous kept one; its ends stay exact."""
    kept = [polyline[0]]
    for vertex in polyline[1:]:
        if np.linalg.norm(vertex - kept[-1]) >= tolerance_m:
            kept.append(vertex)
    if len(kept) > 1:
        kept[-1] = polyline[-1]
    return np.array(kept)


def drop_collinear_vertices(polyline: NDArray[np.float64], max_turn_deg: float = 0.5) -> NDArray[np.float64]:
    """The polyline without interior vertices where it turns by less than max_turn_deg."""
    kept = [polyline[0]]
    for vertex, following in itertools.pairwise(polyline[1:]):
        incoming, outgoing = vertex - kept[-1], following - vertex
        cosine = float(incoming @ outgoing) / max(float(np.linalg.norm(incoming) * np.linalg.norm(outgoing)), _EPS)
        if cosine < np.cos(np.radians(max_turn_deg)):
            kept.append(vertex)
    kept.append(polyline[-1])
    return np.array(kept)


# ----- the camera on the robot ----------------------------------------------------------------------
# D435i RGB sensor (OV2740) at its native 1920×1080: fx ≈ fy ≈ 1380 px, 69.4° × 42.5° field of view
# (Intel D400 series datasheet, rev. 2020). Smaller modes are binned/cropped from it.
_NATIVE_WIDTH, _NATIVE_HEIGHT, _NATIVE_FOCAL_PX = 1920, 1080, 1380.0


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

    def rotation(self) -> NDArray[np.float64]:
        """R_base_camera: columns are the optical x (right), y (down), z (forward-down) axes in base_link."""
        a = math.radians(self.pitch_down_deg)
        x_axis = np.array([0.0, -1.0, 0.0])
        z_axis = np.array([math.cos(a), 0.0, -math.sin(a)])
        y_axis = np.cross(z_axis, x_axis)
        return np.column_stack([x_axis, y_axis, z_axis])

    def transform(self) -> NDArray[np.float64]:
        """T_base_camera as a 4×4 homogeneous matrix."""
        T = np.eye(4)
        T[:3, :3] = self.rotation()
        T[:3, 3] = self.position_m
        return T


# ----- the antenna's lever arm ----------------------------------------------------------------------
# Two forms on purpose: the base's control and the live map use the heading alone (a kiwi base drives in
# the plane; a filter's small roll/pitch must not steer it), registration applies the full rotation.
def yaw_of(pose: Pose) -> float:
    """The heading (rad) of a pose's quaternion (x, y, z, w)."""
    qx, qy, qz, qw = (float(v) for v in pose.orientation)
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def planar_antenna_xy(x: float, y: float, yaw: float, lever_arm: tuple[float, float, float]) -> NDArray[np.float64]:
    """The antenna midpoint (x, y) in the site frame for a base at (x, y) heading `yaw`."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([x + c * lever_arm[0] - s * lever_arm[1], y + s * lever_arm[0] + c * lever_arm[1]])


def antenna_xy(pose: Pose, lever_arm: tuple[float, float, float]) -> NDArray[np.float64]:
    """The antenna midpoint (x, y) in the site frame for a base pose (its heading only)."""
    return planar_antenna_xy(float(pose.position[0]), float(pose.position[1]), yaw_of(pose), lever_arm)


def antenna_positions(poses: Sequence[Pose], lever_arm: tuple[float, float, float]) -> NDArray[np.float64]:
    """Site-frame antenna midpoints (n, 3): each base pose applied to the base-frame lever arm."""
    if len(poses) == 0:
        return np.zeros((0, 3))
    positions = np.array([np.asarray(p.position, dtype=np.float64) for p in poses])
    quats = np.array([np.asarray(p.orientation, dtype=np.float64) for p in poses])
    if positions.shape[1:] != (3,) or quats.shape[1:] != (4,):
        raise InterpretationError("poses need a 3-vector position and an (x, y, z, w) quaternion each")
    try:
        rotations = Rotation.from_quat(quats)  # scipy's order is scalar-last (x, y, z, w), as Pose
    except ValueError as exc:
        raise InterpretationError(
            f"a pose has an invalid orientation quaternion ({exc}); check the pose source (fusion/EKF)"
        ) from exc
    arm = np.asarray(lever_arm, dtype=np.float64)
    return np.asarray(positions + rotations.apply(np.tile(arm, (len(positions), 1))), dtype=np.float64)


# ----- solid rods (pipes as polyline axes with a radius) -------------------------------------------
# Each rod is the union of a cylinder per axis segment (flat ends) and a ball at every interior vertex
# (filling the outer wedge of a bend). The union is sampled uniformly by drawing from the primitives in
# proportion to their volume and keeping a draw only for the first primitive that contains it, which
# cancels the double counting where primitives overlap (bends, tees, crossings); a point in an overlap
# belongs to the rod listed first. The ground truth and the completion both sample with it.
_REGION_ROUNDS = 30  # rounds of drawing before giving up (a region the rods barely touch)
_MAX_BATCH = 1_000_000  # candidate points per round at the most


@dataclass(frozen=True)
class Primitive:
    """A cylinder (start, end, radius) of rod `rod` or, when end is None, a ball (centre = start, radius)."""

    rod: int
    start: NDArray[np.float64]
    end: NDArray[np.float64] | None
    radius: float

    @property
    def volume(self) -> float:
        """The primitive's volume (m³)."""
        if self.end is None:
            return 4.0 / 3.0 * math.pi * self.radius**3
        return math.pi * self.radius**2 * float(np.linalg.norm(self.end - self.start))

    def contains(self, points: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which of the points (..., 3) lie inside."""
        rel = points - self.start
        if self.end is None:
            return np.asarray(np.sum(rel**2, axis=-1) <= self.radius**2)
        ab = self.end - self.start
        s = (rel @ ab) / float(ab @ ab)
        radial = rel - s[..., None] * ab
        return np.asarray((s >= 0.0) & (s <= 1.0) & (np.sum(radial**2, axis=-1) <= self.radius**2))

    def sample(self, count: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """count points uniform inside the primitive."""
        if self.end is None:
            direction = rng.standard_normal((count, 3))
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            return np.asarray(self.start + direction * (self.radius * rng.random(count) ** (1.0 / 3.0))[:, None])
        ab = self.end - self.start
        u = ab / np.linalg.norm(ab)
        e1 = np.cross(u, [0.0, 0.0, 1.0] if abs(u[2]) < 0.9 else [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(u, e1)
        r = self.radius * np.sqrt(rng.random(count))
        phi = 2.0 * math.pi * rng.random(count)
        along = rng.random(count)
        return np.asarray(
            self.start + along[:, None] * ab + (r * np.cos(phi))[:, None] * e1 + (r * np.sin(phi))[:, None] * e2
        )


def rod_primitives(axes: Sequence[NDArray[np.float64]], radii: Sequence[float]) -> list[Primitive]:
    """Cylinders for every segment, then balls at the interior vertices, rod by rod."""
    primitives = []
    for rod, (axis, radius) in enumerate(zip(axes, radii, strict=True)):
        points = np.asarray(axis, dtype=np.float64)
        for a, b in itertools.pairwise(points):
            if np.linalg.norm(b - a) > 1e-9:
                primitives.append(Primitive(rod, a, b, radius))
        primitives += [Primitive(rod, vertex, None, radius) for vertex in points[1:-1]]
    return primitives


def sample_rods(
    axes: Sequence[NDArray[np.float64]], radii: Sequence[float], n: int, rng: np.random.Generator,
    region_xy: tuple[float, float, float, float] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """n points uniform inside the union of the rods, and the rod index of each point.

    With `region_xy` = (xmin, xmax, ymin, ymax) only the rods' part above that area counts; if too little
    of them lies there, fewer than n points come back (the caller says what to change)."""
    primitives = rod_primitives(axes, radii)
    if n <= 0 or not primitives:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    volumes = np.array([p.volume for p in primitives])
    chosen: list[NDArray[np.float64]] = []
    owners: list[NDArray[np.int64]] = []
    have, batch = 0, max(2 * n, 1024)
    for _ in range(_REGION_ROUNDS):
        picks = rng.choice(len(primitives), size=batch, p=volumes / volumes.sum())
        counts = np.bincount(picks, minlength=len(primitives))
        for k, primitive in enumerate(primitives):
            if counts[k] == 0:
                continue
            points = primitive.sample(int(counts[k]), rng)
            # Uniform over the union: a point counts only for the first primitive that contains it.
            keep = (~np.any([primitives[j].contains(points) for j in range(k)], axis=0) if k
                    else np.ones(len(points), bool))
            if region_xy is not None:
                xmin, xmax, ymin, ymax = region_xy
                x, y = points[:, 0], points[:, 1]
                keep &= (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)
            chosen.append(points[keep])
            owners.append(np.full(int(keep.sum()), primitive.rod, dtype=np.int64))
            have += int(keep.sum())
        if have >= n or (have == 0 and batch >= _MAX_BATCH):
            break
        batch = int(min(_MAX_BATCH, batch * (4.0 if have == 0 else max(1.5, 1.2 * n / have))))
    if have == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    all_points, all_owners = np.concatenate(chosen), np.concatenate(owners)
    order = rng.permutation(len(all_points))[:n]
    return all_points[order], all_owners[order]
