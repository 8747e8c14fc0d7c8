"""Two-way travel times of a ground-coupled-in-air common-offset antenna, with refraction at the surface.

Frames: site frame, x forward, y left, z up (REP-103); the ground surface is z = 0 and the subsurface
is z < 0. The antenna rides at height h above the surface with transmitter and receiver separated by
`offset` along a horizontal unit vector. Velocities are in m/ns, times in ns.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

C_M_PER_NS = 0.299792458

FloatArray = NDArray[np.float64]


def velocity_from_eps(eps_r: float) -> float:
    """Wave velocity in m/ns of a low-loss medium of relative permittivity eps_r."""
    return C_M_PER_NS / float(np.sqrt(eps_r))


def eps_from_velocity(v: float) -> float:
    """Relative permittivity of a low-loss medium whose wave velocity is v m/ns."""
    return float((C_M_PER_NS / v) ** 2)


def refracted_leg_time(height: FloatArray, horiz: FloatArray, depth: FloatArray, v: float) -> FloatArray:
    """One-way time from a point `height` m above the surface to a point `depth` m below it.

    `horiz` is the horizontal distance between the two points. The ray bends at the surface (Snell);
    the bending point is found by Newton iterations on Fermat's travel time, which is convex. An antenna
    on the surface (height 0) sends straight rays into the ground: Fermat's path would run along the
    surface in the air (a lateral wave, weak), while the FDTD scenes with a source at the surface
    follow the straight ray within 20-30 ps.
    """
    h = np.maximum(np.asarray(height, dtype=np.float64), 0.0)
    D = np.abs(np.asarray(horiz, dtype=np.float64))
    d = np.maximum(np.asarray(depth, dtype=np.float64), 1e-6)
    if not np.any(h > 1e-6):
        return np.asarray(np.sqrt(d * d + D * D) / v)
    c = C_M_PER_NS
    # Start from the straight-line crossing point: a good guess when h << d.
    a = D * h / np.maximum(h + d, 1e-9)
    for _ in range(6):
        ra = np.sqrt(h * h + a * a)
        rb = np.sqrt(d * d + (D - a) ** 2)
        g = a / (c * np.maximum(ra, 1e-12)) - (D - a) / (v * rb)
        gp = h * h / (c * np.maximum(ra, 1e-12) ** 3) + d * d / (v * rb**3)
        a = np.clip(a - g / np.maximum(gp, 1e-12), 0.0, D)
    refracted = np.sqrt(h * h + a * a) / c + np.sqrt(d * d + (D - a) ** 2) / v
    return np.asarray(np.where(h > 1e-6, refracted, np.sqrt(d * d + D * D) / v))


def two_way_time(
    mid_xy: FloatArray,
    point: FloatArray,
    v: float,
    height: float,
    offset: float,
    offset_dir: FloatArray,
) -> FloatArray:
    """Two-way time (ns) from Tx to a subsurface point and back to Rx.

    `mid_xy` (..., 2): horizontal position of the antenna midpoint; `point` (..., 3): the reflector
    point (z < 0); `offset_dir` (2,): horizontal unit vector from Rx to Tx. Shapes broadcast.
    """
    mid = np.asarray(mid_xy, dtype=np.float64)
    p = np.asarray(point, dtype=np.float64)
    half = 0.5 * offset * np.asarray(offset_dir, dtype=np.float64)
    depth = -p[..., 2]
    t = np.zeros(np.broadcast_shapes(mid.shape[:-1], p.shape[:-1]))
    for sign in (1.0, -1.0):
        ant = mid + sign * half
        horiz = np.hypot(p[..., 0] - ant[..., 0], p[..., 1] - ant[..., 1])
        t = t + refracted_leg_time(np.full_like(horiz, height), horiz, depth, v)
    return t


def cylinder_specular_point(
    mid_xy: FloatArray, axis_a: FloatArray, axis_b: FloatArray, radius: float
) -> tuple[FloatArray, FloatArray]:
    """The point of a pipe segment's surface nearest to the ground point under the antenna.

    Returns (surface point (..., 3), distance from the ground point to the axis (...,)). The
    specular point of a cylinder seen from a point lies on the line from that point to its nearest
    axis point; taking the ground point under the antenna (not the antenna itself) is exact for a
    zero-height antenna only. Above the ground the reflecting ray is the refracted one aimed at the
    axis, so the true point lies nearer the pipe's top: at 5 cm height and eps_r 8 this point makes a
    10 cm pipe's far flank later than a point target's, where it is earlier (a known error of our
    forward model and of the chain's fits; see issue 12's notes, branch exp/specular-geometry).
    """
    g = np.zeros((*np.asarray(mid_xy).shape[:-1], 3))
    g[..., :2] = mid_xy
    a = np.asarray(axis_a, dtype=np.float64)
    ab = np.asarray(axis_b, dtype=np.float64) - a
    L2 = max(float(ab @ ab), 1e-12)
    s = np.clip(((g - a) @ ab) / L2, 0.0, 1.0)
    nearest = a + s[..., None] * ab
    to_g = g - nearest
    dist = np.linalg.norm(to_g, axis=-1)
    unit = to_g / np.maximum(dist, 1e-12)[..., None]
    return nearest + radius * unit, dist
