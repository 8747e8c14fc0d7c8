"""A pipe fitted to one hyperbola's picks at a known velocity: centre, radius and crossing angle.

On one line the crossing angle trades off against the radius (an oblique pipe gives a wider
hyperbola) and the radius against the depth of the centre, so priors from the other lines enter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from gprbot.config import GprConfig
from gprbot.gpr.hyperbola import MAX_RADIUS_M
from gprbot.gpr.line_model import cylinder_times, depth_for_apex_time

FloatArray = NDArray[np.float64]

PICK_STD_NS = 0.005  # typical pick scatter: weighs a crossing-angle prior against the picks
DEFAULT_SIN_STD = 0.05  # no twin on the neighbouring lines: "roughly at right angles" (s = 0.95 is 72°)
MIN_SIN_CROSS = 0.34  # pipes crossing a line at under 20° do not make hyperbolas


@dataclass(frozen=True)
class CylinderFit:
    """A pipe fitted to one hyperbola: centre (x0, dc), radius, crossing sine, RMS misfit (ns), picks used."""

    x0_m: float
    depth_m: float
    radius_m: float
    sin_cross: float
    rms_ns: float
    n_picks: int
    inner_echo: bool


def fit_cylinder(
    x_m: FloatArray, t_ns: FloatArray, v: float, gpr: GprConfig, *,
    sin_prior: tuple[float, float] = (1.0, DEFAULT_SIN_STD),
    radius_m: float | None = None,
    lateral_m: FloatArray | None = None,
    cot_sign: float = 0.0,
) -> CylinderFit:
    """Least-squares cylinder (x0, dc, R, s) through picks at a known velocity, outliers rejected.

    `sin_prior` (mean, std) is a prior on the crossing sine s — from the neighbouring lines, or
    "about at right angles" — because on one line s trades off against R. With `radius_m` given the
    radius is held (it came from the inner echo). `lateral_m` (per pick) is the antenna's sideways
    offset from the line's axis, which moves an oblique pipe's crossing by lateral · cot φ; `cot_sign`
    says which way (see `velocity.link_crossing_angles`). A robust fit from several starts, then picks off
    by more than 3σ after a redescending (Cauchy) fit — crossing flanks — are dropped and it is refitted.
    """
    apex = int(np.argmin(t_ns))
    z_top = depth_for_apex_time(float(t_ns[apex]), v, gpr)
    x_apex = float(x_m[apex])
    s_mean, s_std = sin_prior
    held = radius_m is not None
    lb = [x_apex - 0.2, 0.005, MIN_SIN_CROSS] + ([] if held else [0.0])
    ub = [x_apex + 0.2, 3.0, 1.0] + ([] if held else [MAX_RADIUS_M])
    keep = np.ones(len(x_m), dtype=bool)

    def radius_of(p: FloatArray) -> float:
        return float(radius_m) if radius_m is not None else float(p[3])

    lateral = np.zeros(len(x_m)) if lateral_m is None else np.asarray(lateral_m, dtype=np.float64)

    def residual(p: FloatArray) -> FloatArray:
        shift = lateral[keep] * (cot_sign * math.sqrt(max(0.0, 1.0 - p[2] * p[2])) / p[2])
        times = cylinder_times(x_m[keep] - shift, p[0], p[1], radius_of(p), v, gpr, p[2]) - t_ns[keep]
        return np.append(times, PICK_STD_NS * (p[2] - s_mean) / s_std)

    best: optimize.OptimizeResult | None = None
    starts = sorted({min(1.0, s_mean), 0.75}) if s_std >= DEFAULT_SIN_STD else [min(1.0, s_mean)]
    for r0 in [float(radius_m)] if radius_m is not None else [0.01, 0.04]:
        for s0 in starts:
            p0 = [x_apex, z_top + r0, s0] + ([] if held else [r0])
            sol = optimize.least_squares(residual, np.clip(p0, lb, ub), bounds=(lb, ub), loss="soft_l1",
                                         f_scale=0.01, x_scale="jac")
            if best is None or sol.cost < best.cost:
                best = sol
    assert best is not None
    # A redescending loss lets crossing flanks go, then they are dropped for good.
    best = optimize.least_squares(residual, best.x, bounds=(lb, ub), loss="cauchy", f_scale=0.004, x_scale="jac")
    r = residual(best.x)[:-1]
    sigma = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    keep = np.abs(r) < max(3.0 * sigma, 0.008)
    if keep.sum() >= 5:
        best = optimize.least_squares(residual, best.x, bounds=(lb, ub), loss="soft_l1", f_scale=0.004,
                                      x_scale="jac")
    r = residual(best.x)[:-1]
    return CylinderFit(float(best.x[0]), float(best.x[1]), radius_of(best.x), float(best.x[2]),
                       math.sqrt(float(np.mean(r**2))), int(keep.sum()), held)
