"""The velocity from one target whose top depth the user knows (a cover meter reading, a core, a drawing).

One hyperbola cannot give the velocity to a few per cent when its radius is unknown: a velocity 5 % off
fits the curve as well with another radius and top (`validation.hyperbola_signatures`: within 0.015
periods on every FDTD dev pipe). Its apex time is measured, though, and so is the depth of its top at any
velocity; a known cover therefore fixes the velocity: the one at which the refracted two-way time from
the antenna to that depth (the antenna's height and Tx-Rx offset as configured) equals the apex time.
This is how GPR users calibrate depths on site. One known top leaves the apex's own lag (time zero, the
wavelet) in the velocity; two at depths well apart in time fix both: the velocity from their spacing,
time zero from where they sit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gprbot.gpr.chain.fit import PICK_STD_PERIODS, V_BOUNDS, CylinderFit
from gprbot.gpr.chain.geometry import cylinder_time
from gprbot.gpr.chain.prepare import PreparedBScan
from gprbot.gpr.chain.reflectors import Reflector
from gprbot.gpr.chain.velocity import VelocityEstimate

SEARCH_M = 0.05  # a hyperbola whose apex lies this far from the given position is that target
NEAR_M = 0.02  # searched first: a cover meter places a bar to a centimetre or two
BISECTIONS = 60
TIME_ZERO_PERIODS = 0.1
MIN_SPAN_PERIODS = 2.0  # two known tops closer in time than this do not separate the velocity from time zero


@dataclass(frozen=True)
class KnownTop:
    """A target's along-track position and the depth of its top below the surface (m), and how well known."""

    x_m: float
    top_m: float
    tolerance_m: float = 0.005

    def __post_init__(self) -> None:
        if not (math.isfinite(self.x_m) and math.isfinite(self.top_m) and self.top_m > 0.0):
            raise ValueError(f"a known top needs a finite position and a depth > 0 m (got x {self.x_m}, "
                             f"depth {self.top_m})")


def apex_time(prep: PreparedBScan, fit: CylinderFit) -> float:
    """Two-way time (ns after time zero) of a fitted curve at its apex."""
    x = np.array([fit.x0_m])
    return float(cylinder_time(x, fit.x0_m, fit.depth_m, fit.radius_m, fit.v, prep.antenna_height_m,
                               prep.tx_rx_offset_m)[0])


def top_times(prep: PreparedBScan, tops_m: Sequence[float] | float, v: float) -> np.ndarray:
    """Refracted two-way times (ns) from the antenna straight above to points `tops_m` deep, at velocity v."""
    depths = np.asarray(tops_m, dtype=np.float64)
    return np.asarray(cylinder_time(np.zeros_like(depths), 0.0, depths, 0.0, v, prep.antenna_height_m,
                                    prep.tx_rx_offset_m))


def velocity_for(prep: PreparedBScan, t_ns: float, top_m: float) -> float | None:
    """The velocity at which a top `top_m` deep arrives at `t_ns`; None where no velocity in bounds does."""
    lo, hi = V_BOUNDS
    if not float(top_times(prep, top_m, hi)) <= t_ns <= float(top_times(prep, top_m, lo)):  # falls as v grows
        return None
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if float(top_times(prep, top_m, mid)) > t_ns else (lo, mid)
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class Apex:
    """A known top and the hyperbola found at its position, with that hyperbola's apex time (ns)."""

    known: KnownTop
    reflector: Reflector
    t_ns: float


def apex_near(prep: PreparedBScan, reflectors: Sequence[Reflector], known: KnownTop,
              prior_v: float | None = None) -> Apex | None:
    """The hyperbola of the target at `known.x_m` and its apex time; None without one there.

    The target's top is the earliest apex at its position: under it lie its echoes (ringing, a pipe's
    bottom, multiples: FDTD dev, the nearest apex was an echo on 3 of 20 scenes). A neighbour a few
    centimetres aside may be earlier, so the closest window that holds an apex is searched first. With a
    `prior_v` (a survey's estimate from all its hyperbolas), the apex whose time puts the known depth at the
    velocity nearest it is taken instead: a pipe under a shallower pipe or a bar has earlier apexes within
    a few centimetres of its own (FDTD dev surveys: +226 % from a bar's apex over a 30 cm deep pipe).
    """
    for window in (NEAR_M, SEARCH_M):
        near = [(apex_time(prep, r.free_fit), r) for r in reflectors if abs(r.free_fit.x0_m - known.x_m) <= window]
        if prior_v is not None:
            near_v = [(abs(math.log(v / prior_v)), t, r) for t, r in near
                      if (v := velocity_for(prep, t, known.top_m)) is not None]
            if near_v:
                _, t, r = min(near_v, key=lambda dtr: dtr[0])
                return Apex(known, r, t)
            continue
        if near:
            t, r = min(near, key=lambda tr: tr[0])
            return Apex(known, r, t)
    return None


def _pick_sigma(prep: PreparedBScan) -> float:
    """One pick's timing error (ns)."""
    return max(PICK_STD_PERIODS * prep.period_ns, 0.5 * prep.dt_ns)


def calibrated_velocity(prep: PreparedBScan, apex: Apex) -> VelocityEstimate | None:
    """The velocity that puts the hyperbola at the known top's position at its depth; None where none in bounds does."""
    known, t = apex.known, apex.t_ns
    v = velocity_for(prep, t, known.top_m)
    if v is None:
        return None
    # One-sigma: the apex time to a pick's error and time zero's (the direct wave's envelope peak, less the
    # air path, lies 30-130 ps before the source peak on the FDTD dev half: about a tenth of a period), the
    # depth to the user's tolerance. On a shallow top these dominate, and the interval says so.
    sigma_t = math.hypot(_pick_sigma(prep), TIME_ZERO_PERIODS * prep.period_ns)
    spread = [velocity_for(prep, t + dt, known.top_m + dz) for dt, dz in
              ((sigma_t, 0.0), (0.0, known.tolerance_m))]
    sigma = math.sqrt(sum((s - v) ** 2 for s in spread if s is not None))
    how = (f"calibrated on the known top at x {known.x_m:.3f} m, {100 * known.top_m:.1f} cm deep "
           f"(hyperbola at x {apex.reflector.free_fit.x0_m:.3f} m, apex {t:.3f} ns after time zero)")
    return VelocityEstimate(v, sigma, 1, how)


@dataclass(frozen=True)
class TwoPointCalibration:
    """Velocity (m/ns) and its 1-sigma, and the shift of time zero (ns) that known tops at two depths fix."""

    v: float
    sigma: float
    t0_shift_ns: float
    method: str


def _joint_fit(prep: PreparedBScan, times: Sequence[float], tops: Sequence[float]) -> tuple[float, float] | None:
    """(velocity, time shift) minimising the apex times' misfit to the refracted times of the known tops."""
    def shift_and_misfit(v: float) -> tuple[float, float]:
        residual = np.asarray(times) - top_times(prep, tops, v)
        shift = float(residual.mean())
        return shift, float(np.sum((residual - shift) ** 2))

    grid = np.geomspace(V_BOUNDS[0], V_BOUNDS[1], 400)
    misfits = [shift_and_misfit(float(v))[1] for v in grid]
    k = int(np.argmin(misfits))
    if k in (0, len(grid) - 1):
        return None  # no velocity in bounds explains the tops' spacing in time
    lo, hi = float(grid[k - 1]), float(grid[k + 1])
    for _ in range(BISECTIONS):  # golden-section search of the bracket
        a, b = lo + 0.382 * (hi - lo), lo + 0.618 * (hi - lo)
        lo, hi = (lo, b) if shift_and_misfit(a)[1] < shift_and_misfit(b)[1] else (a, hi)
    v = 0.5 * (lo + hi)
    return v, shift_and_misfit(v)[0]


def two_point_calibration(prep: PreparedBScan, apexes: Sequence[Apex]) -> TwoPointCalibration | None:
    """Velocity and time zero from known tops at least MIN_SPAN_PERIODS apart in time; None where fewer are found.

    One known top cannot tell the velocity from a late apex (time zero and the wavelet's lag: the one-top
    calibration reads 3-6 % slow on the FDTD dev half); two at different depths can, from their spacing in time.
    """
    if len(apexes) < 2:
        return None
    times = [a.t_ns for a in apexes]
    if max(times) - min(times) < MIN_SPAN_PERIODS * prep.period_ns:
        return None
    tops = [a.known.top_m for a in apexes]
    fit = _joint_fit(prep, times, tops)
    if fit is None:
        return None
    v, shift = fit
    # One-sigma from the spacing: a pick's error on each of the outermost, and the users' depth tolerances.
    span = max(tops) - min(tops)
    sigma_t = math.sqrt(2.0) * _pick_sigma(prep) / (max(times) - min(times))
    sigma_d = math.hypot(*(a.known.tolerance_m for a in apexes[:2])) / span
    sigma = v * math.hypot(sigma_t, sigma_d)
    how = (f"calibrated on {len(apexes)} known tops {100 * min(tops):.1f}-{100 * max(tops):.1f} cm deep "
           f"(velocity from their spacing in time; time zero moved {1000 * shift:+.0f} ps)")
    return TwoPointCalibration(v, sigma, shift, how)


@dataclass(frozen=True)
class Calibration:
    """What known tops gave: the velocity (None: none used), the shift of time zero (ns), notes for the user."""

    estimate: VelocityEstimate | None
    t0_shift_ns: float
    notes: tuple[str, ...]


def calibrate(prep: PreparedBScan, reflectors: Sequence[Reflector], known: Sequence[KnownTop],
              prior_v: float | None = None) -> Calibration:
    """The velocity from known tops: two apart in depth fix time zero too; else the median of single calibrations.
    `prior_v`: a rough velocity that tells a known top's apex from its neighbours' (`apex_near`)."""
    found = {k: apex_near(prep, reflectors, k, prior_v) for k in known}
    apexes = [a for a in found.values() if a is not None]
    notes = [f"no hyperbola within {100 * SEARCH_M:.0f} cm of x {k.x_m:.3f} m: the known top there "
             f"({100 * k.top_m:.1f} cm) was not used; check its position (metres from the first trace)"
             for k, a in found.items() if a is None]
    two = two_point_calibration(prep, apexes)
    if two is not None:
        return Calibration(VelocityEstimate(two.v, two.sigma, len(known), two.method), two.t0_shift_ns, tuple(notes))
    singles = sorted((c for c in (calibrated_velocity(prep, a) for a in apexes) if c is not None), key=lambda c: c.v)
    if not singles and apexes:
        tops = ", ".join(f"{100 * a.known.top_m:.1f} cm at x {a.known.x_m:.3f} m" for a in apexes)
        notes.append(f"no velocity from {V_BOUNDS[0]} to {V_BOUNDS[1]} m/ns puts the hyperbola there at the known "
                     f"depth ({tops}): not used; check the depth (metres below the surface to the target's top)")
    return Calibration(singles[(len(singles) - 1) // 2] if singles else None, 0.0, tuple(notes))
