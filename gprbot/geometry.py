"""Small 3-D geometry on lines, segments and polylines used by the pipe fit (pure numpy)."""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray

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
