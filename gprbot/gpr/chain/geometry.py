"""Two-way times of a common-offset antenna above the ground to a cylinder crossing the line at right angles.

The fits evaluate this thousands of times, so it is the lean form of `traveltime.two_way_time`: rays
refract at the surface (Snell), the bending point found by Newton's method from the better of the paraxial
and critical-angle limits, two iterations to under a picosecond.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gprbot.gpr.traveltime import C_M_PER_NS

FloatArray = NDArray[np.float64]
_NEWTON_STEPS = 2


def leg_time(height: float, horiz: FloatArray, depth: FloatArray, v: FloatArray | float) -> FloatArray:
    """One-way time (ns) from an antenna `height` m above the surface to a point `depth` m below, `horiz` away.

    Fermat's refracted ray (Snell at the surface), its bending point found by Newton's method; beyond
    the critical angle it runs near-grazing in the air, which flattens the flanks (the FDTD scenes with
    a dipole 1-4 cm up fit this within 20-40 ps rms, straight rays from the footprint 100-450 ps). An
    antenna at height 0 is a source in the surface: straight rays (FDTD: 28 ps rms).
    """
    d = np.maximum(np.asarray(depth, dtype=np.float64), 1e-6)
    D = np.abs(np.asarray(horiz, dtype=np.float64))
    if height <= 1e-6:
        return np.asarray(np.sqrt(D * D + d * d) / v)
    a = _bend_point(height, D, d, v)
    return np.asarray(np.sqrt(height * height + a * a) / C_M_PER_NS + np.sqrt(d * d + (D - a) ** 2) / v)


def _bend_point(h: float, D: FloatArray, d: FloatArray, v: FloatArray | float) -> FloatArray:
    """Horizontal distance from the antenna to where the ray enters the ground (Fermat, Newton's method)."""
    c = C_M_PER_NS
    hc, h2, d2 = h * c, h * h, d * d
    # Start from the better of two limits: paraxial Snell, a / (h c) = (D - a) / (d v), near the vertical,
    # and the critical angle in the ground, D - a = d tan(θc), far out. From the paraxial start alone three
    # steps left up to 80 ps near grazing; from this one two steps stay under a picosecond.
    sin_c = np.minimum(v / c, 0.999)
    a = np.maximum(D * hc / (v * d + hc), D - d * (sin_c / np.sqrt(1.0 - sin_c * sin_c)))
    # Written for small arrays (the fits call this ~10⁵ times a line): no np.clip, no powers, and the
    # products c·ra and v·rb made once each (the same values as writing them out twice).
    for _ in range(_NEWTON_STEPS):
        ra2 = h2 + a * a
        rest = D - a
        rb2 = d2 + rest * rest
        c_ra, v_rb = c * np.sqrt(ra2), v * np.sqrt(rb2)
        g = a / c_ra - rest / v_rb
        gp = h2 / (c_ra * ra2) + d2 / (v_rb * rb2)
        a = np.minimum(np.maximum(a - g / gp, 0.0), D)
    return np.asarray(a)


def cylinder_time(
    x_m: FloatArray, x0: FloatArray | float, centre_depth: FloatArray | float, radius: FloatArray | float,
    v: FloatArray | float, height: float, offset: float,
) -> FloatArray:
    """Two-way time (ns) at midpoints x_m to a cylinder (axis across the line) at x0, centre depth, radius.

    The cylinder parameters broadcast against x_m (a batch of cylinders, each with its own picks).
    Both legs go to the point of the cylinder's surface nearest the ground point under the antenna's
    midpoint: the reflection point of a monostatic antenna, and within picoseconds of the bistatic
    (Fermat) point for offsets smaller than the depth.
    """
    ax = np.asarray(x_m, dtype=np.float64) - x0
    if np.ndim(radius) == 0 and radius == 0.0:
        # A point reflects at itself: the shrink below is exactly 1 (0 / dist), so skip it (and its hypot).
        px, pz = np.broadcast_arrays(ax, np.asarray(centre_depth, dtype=np.float64))
    else:
        dist = np.maximum(np.hypot(ax, centre_depth), 1e-9)
        shrink = 1.0 - radius / dist
        px, pz = ax * shrink, centre_depth * shrink  # the point, from under the midpoint, and its depth
    legs = leg_time(height, _two_legs(px, offset), _one_depth(pz), _stacked(v))
    return np.asarray(legs[0] + legs[1])


def _two_legs(px: FloatArray, offset: float) -> FloatArray:
    """The point's horizontal distances from the two antennas, on a new leading axis of two (Tx, Rx).

    Both legs in one call: half the numpy calls of two. Adding -offset/2 is the same float operation as
    subtracting offset/2, and one broadcast addition costs less than two and a stack.
    """
    half = 0.5 * offset
    return np.asarray(px + np.array([-half, half]).reshape((2,) + (1,) * np.ndim(px)))


def _one_depth(pz: FloatArray | float) -> FloatArray:
    """The point's depth given a leading axis of one: both legs share it (broadcast, not stacked)."""
    return np.asarray(pz, dtype=np.float64)[None]


def _stacked(v: FloatArray | float) -> FloatArray | float:
    """A velocity array given a leading axis of one, to broadcast against the two stacked legs."""
    return v if np.ndim(v) == 0 else np.asarray(v)[None]


def _leg_with_gradient(
    height: float, horiz: FloatArray, depth: FloatArray, v: FloatArray | float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """One leg's time and its derivatives by the signed horizontal distance, the depth and the velocity.

    Fermat: the time is stationary in the bending point, so the derivatives are those of the ground
    segment alone (envelope theorem).
    """
    c = C_M_PER_NS
    d = np.maximum(np.asarray(depth, dtype=np.float64), 1e-6)
    signed = np.asarray(horiz, dtype=np.float64)
    D = np.abs(signed)
    a = _bend_point(height, D, d, v) if height > 1e-6 else np.zeros_like(D)
    rest = D - a
    rb = np.sqrt(d * d + rest * rest)
    t = np.sqrt(max(height, 0.0) ** 2 + a * a) / c + rb / v
    v_rb = v * rb
    return t, np.sign(signed) * rest / v_rb, d / v_rb, -rb / (np.asarray(v) ** 2)


def cylinder_time_gradient(
    x_m: FloatArray, x0: FloatArray | float, centre_depth: FloatArray | float, radius: FloatArray | float,
    v: FloatArray | float, height: float, offset: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """`cylinder_time` and its derivatives by x0, the centre depth, the radius (centre held) and v."""
    ax = np.asarray(x_m, dtype=np.float64) - x0
    zc = np.asarray(centre_depth, dtype=np.float64)
    R = np.asarray(radius, dtype=np.float64)
    dist = np.maximum(np.hypot(ax, zc), 1e-9)
    shrink = 1.0 - R / dist
    px, pz = ax * shrink, zc * shrink
    k = R / dist**3
    k_zc = k * zc  # k·zc·zc and k·zc·ax both start from it (evaluated left to right)
    dpx_dax, dpx_dzc, dpx_dR = 1.0 - k_zc * zc, k * ax * zc, -ax / dist
    dpz_dax, dpz_dzc, dpz_dR = k_zc * ax, 1.0 - k * ax * ax, -zc / dist
    t, dD, dd, dv = _leg_with_gradient(height, _two_legs(px, offset), _one_depth(pz), _stacked(v))
    dD, dd = dD[0] + dD[1], dd[0] + dd[1]  # the chain-rule factors below are the same for both legs
    return (t[0] + t[1], -(dD * dpx_dax + dd * dpz_dax), dD * dpx_dzc + dd * dpz_dzc, dD * dpx_dR + dd * dpz_dR,
            dv[0] + dv[1])
