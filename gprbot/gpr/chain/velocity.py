"""Stage 3: the wave velocity from many diffractions at once, with its uncertainty and how it was found.

On one hyperbola radius and velocity trade off (a larger pipe at a lower velocity has nearly the same
curve over the usable aperture), so fitting curves to picks gives a poor velocity: on the FDTD dev half
free fits were off by 8-70 %. Migration does not share that trade-off: at the right velocity a
diffraction, a bar or a pipe's top collapses into its reflector — a point or a short arc — and the
migrated amplitude peaks there. So each hyperbola is migrated locally (a window around its apex) at a
ladder of trial velocities, coarse then fine; the velocity where its peak amplitude is highest is its
vote. The line's velocity is the weighted median of the votes (weights: how sharply each peaks and how
strong it is); its uncertainty the weighted spread of the votes over √n, never below a quarter step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.gpr.chain.prepare import PreparedBScan
from gprbot.gpr.chain.reflectors import Reflector
from gprbot.gpr.migration import kirchhoff_migrate

FloatArray = NDArray[np.float64]

V_MIN, V_MAX = 0.05, 0.25  # m/ns: wet clay … dry sand; concrete is 0.08-0.15
COARSE_STEPS = 13
FINE_STEPS = 5
APERTURE_DEG = 50.0
WINDOW_X_M = 0.05
MAX_VOTERS = 8
MIN_FLANK = 3
MIN_CONTRAST = 1.15  # a focus curve whose peak is not this far above its ends says nothing


@dataclass(frozen=True)
class VelocityEstimate:
    """The velocity (m/ns), its 1-sigma uncertainty, the number of diffractions used, and how."""

    v: float
    sigma: float
    n_used: int
    method: str


def focus(prep: PreparedBScan, column: int, apex_t_ns: float, velocities: FloatArray) -> FloatArray:
    """Peak migrated amplitude near a hyperbola's apex at each trial velocity."""
    out = np.zeros(len(velocities))
    half = max(2, round(WINDOW_X_M / prep.dx_m))
    for k, v in enumerate(velocities):
        top = 0.5 * float(v) * apex_t_ns
        z = np.arange(max(0.002, top - 0.03), top + 0.04, 0.002)
        reach = math.ceil((top + 0.04) * math.tan(math.radians(APERTURE_DEG)) / prep.dx_m) + half
        lo, hi = max(0, column - reach), min(prep.data.shape[0], column + reach + 1)
        image = kirchhoff_migrate(prep.data[lo:hi], prep.x_m[lo:hi], prep.dt_ns, prep.t0_ns, z, float(v),
                                  antenna_height_m=prep.antenna_height_m, tx_rx_offset_m=prep.tx_rx_offset_m,
                                  aperture_deg=APERTURE_DEG)
        c = column - lo
        out[k] = float(np.abs(image[:, max(0, c - half) : c + half + 1]).max())
    return out


def _peak(curve: FloatArray, velocities: FloatArray) -> float | None:
    """Sub-step velocity of the curve's interior maximum (log-spaced ladder); None at an end."""
    i = int(np.argmax(curve))
    if i in (0, len(curve) - 1):
        return None
    a, b, c = curve[i - 1], curve[i], curve[i + 1]
    denom = a - 2.0 * b + c
    frac = 0.0 if denom >= 0 else float(np.clip(0.5 * (a - c) / denom, -0.5, 0.5))
    lv = np.log(velocities)
    return float(np.exp(lv[i] + frac * (lv[1] - lv[0])))


def vote(prep: PreparedBScan, r: Reflector) -> tuple[float, float] | None:
    """One hyperbola's velocity and weight, from its focus curve (coarse ladder, then fine)."""
    coarse = np.geomspace(V_MIN, V_MAX, COARSE_STEPS)
    curve = focus(prep, r.candidate.column, r.candidate.t_ns, coarse)
    best = _peak(curve, coarse)
    contrast = float(curve.max() / max(min(curve[0], curve[-1]), 1e-30))
    if best is None or contrast < MIN_CONTRAST:
        return None
    step = float(np.log(coarse[1] / coarse[0]))
    fine = best * np.exp(np.linspace(-step, step, FINE_STEPS))
    v = _peak(focus(prep, r.candidate.column, r.candidate.t_ns, fine), fine) or best
    return v, math.log(contrast) * math.log1p(r.candidate.snr)


def estimate_velocity(prep: PreparedBScan, reflectors: Sequence[Reflector]) -> VelocityEstimate | None:
    """The velocity the hyperbolas' migration focus agrees on; None when no hyperbola focuses."""
    two_sided = [r for r in reflectors
                 if min(r.picks.left, r.picks.right) >= max(MIN_FLANK, 0.25 * max(r.picks.left, r.picks.right))]
    two_sided.sort(key=lambda r: -r.candidate.snr)
    votes = [v for v in (vote(prep, r) for r in two_sided[:MAX_VOTERS]) if v is not None]
    if not votes:
        return None
    v, w = np.array([x[0] for x in votes]), np.array([x[1] for x in votes])
    order = np.argsort(v)
    cum = np.cumsum(w[order])
    median = float(v[order][np.searchsorted(cum, 0.5 * cum[-1])])
    spread = float(np.sqrt(np.sum(w * np.log(v / median) ** 2) / np.sum(w)))
    step = math.log(V_MAX / V_MIN) / (COARSE_STEPS - 1) / (FINE_STEPS - 1) * 2.0
    n = len(votes)
    sigma_rel = max(spread / math.sqrt(n), 0.25 * step) if n > 1 else max(spread, step)
    how = (f"migration focus of {n} diffraction hyperbolas (weighted median)" if n > 1
           else "the migration focus of one diffraction hyperbola")
    return VelocityEstimate(median, median * sigma_rel, n, how)
