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
# (filling the outer wedge of a bend). The union of all rods is sampled uniformly by drawing from the
# primitives in proportion to their volume and keeping a draw with probability 1 / (number of primitives
# that contain it), which cancels the double counting where primitives overlap (bends, tees, crossings).
# The ground truth and the completion both sample with it, so they sample alike.
_CONTAIN_EPS = 1e-9
_REGION_ROUNDS = 30  # with a region: rounds of drawing before giving up on a region the rods barely touch
_MAX_DRAW = 1_000_000  # draws per round at the most


@dataclass(frozen=True)
class Primitive:
    """A cylinder (start, end, radius) or, when end is None, a ball (centre = start, radius)."""

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
        """Which points (..., 3) lie inside (a small tolerance for rounding)."""
        rel = points - self.start
        r2 = self.radius**2 + _CONTAIN_EPS
        if self.end is None:
            return np.asarray(np.sum(rel**2, axis=-1) <= r2)
        axis = self.end - self.start
        length2 = float(axis @ axis)
        t = rel @ axis / length2
        radial2 = np.sum(rel**2, axis=-1) - t * t * length2
        return np.asarray((t >= -_CONTAIN_EPS) & (t <= 1.0 + _CONTAIN_EPS) & (radial2 <= r2))

    def sample(self, count: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """count points uniform inside the primitive."""
        if self.end is None:
            direction = rng.normal(size=(count, 3))
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            return self.start + direction * (self.radius * rng.random(count) ** (1.0 / 3.0))[:, None]
        axis = self.end - self.start
        unit = axis / np.linalg.norm(axis)
        helper = np.array([1.0, 0.0, 0.0]) if abs(unit[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = np.cross(unit, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(unit, e1)
        radial = self.radius * np.sqrt(rng.random(count))
        angle = rng.uniform(0.0, 2.0 * math.pi, count)
        along = rng.random(count)
        return np.asarray(
            self.start
            + np.outer(along, axis)
            + np.outer(radial * np.cos(angle), e1)
            + np.outer(radial * np.sin(angle), e2),
            dtype=np.float64,
        )


def rod_primitives(axes: Sequence[NDArray[np.float64]], radii: Sequence[float]) -> list[Primitive]:
    """Cylinders for every segment and balls at interior vertices of each rod."""
    primitives = []
    for rod, (axis, radius) in enumerate(zip(axes, radii, strict=True)):
        for a, b in itertools.pairwise(axis):
            if np.linalg.norm(b - a) > 1e-9:
                primitives.append(Primitive(rod, a, b, radius))
        primitives += [Primitive(rod, vertex, None, radius) for vertex in axis[1:-1]]
    return primitives


def sample_rods(
    axes: Sequence[NDArray[np.float64]], radii: Sequence[float], n: int, rng: np.random.Generator,
    region_xy: tuple[float, float, float, float] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """n points uniform inside the union of the rods, and the rod index of each point.

    With `region_xy` = (xmin, xmax, ymin, ymax) only the rods' part above that area counts; if too little
    of them lies there, fewer than n points come back (the caller says what to change)."""
    primitives = rod_primitives(axes, radii)
    if n <= 0 or not primitives:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.intp)
    volumes = np.array([p.volume for p in primitives])
    weights = volumes / volumes.sum()
    points: list[NDArray[np.float64]] = []
    labels: list[NDArray[np.intp]] = []
    have, draw, rounds = 0, int(1.5 * n) + 16, 0
    while have < n and rounds < (_REGION_ROUNDS if region_xy is not None else math.inf):
        counts = rng.multinomial(draw, weights)
        got = 0
        for primitive, count in zip(primitives, counts, strict=True):
            if count == 0:
                continue
            draws = primitive.sample(int(count), rng)
            cover = np.maximum(sum(p.contains(draws).astype(np.intp) for p in primitives), 1)
            keep = rng.random(len(draws)) * cover < 1.0  # uniform over the union: overlaps are not counted twice
            if region_xy is not None:
                xmin, xmax, ymin, ymax = region_xy
                keep &= (draws[:, 0] >= xmin) & (draws[:, 0] <= xmax) & (draws[:, 1] >= ymin) & (draws[:, 1] <= ymax)
            points.append(draws[keep])
            labels.append(np.full(int(np.count_nonzero(keep)), primitive.rod, dtype=np.intp))
            got += int(np.count_nonzero(keep))
        have, rounds = have + got, rounds + 1
        draw = int(1.5 * (n - have)) + 16
        if region_xy is not None:  # a region keeps a fraction of the draws: ask for enough next round
            draw = int(min(_MAX_DRAW, draw / max(got / float(counts.sum()), 1e-3)))
    if have == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.intp)
    order = rng.permutation(have)[:n]
    return np.concatenate(points)[order], np.concatenate(labels)[order]
