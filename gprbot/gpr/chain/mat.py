"""Stage 1b: a rebar mat's periodic response, found and taken out of the line that is searched below it.

A mat's bars cross the line every few tens of centimetres; their hyperbolas, their ringing and the crossings of
their flanks repeat along the line with that period. At 10-15 cm each bar's flanks cross its neighbours' within a
few centimetres, so no bar's picks make a hyperbola, and the mat's events fill the apex candidates' seats, so a
pipe below it is never looked at (the FDTD mesh batch, validation/README.md). What repeats with the mat's period
is the mat; a pipe does not repeat. The period is read from the lateral autocorrelation of the envelope (a trough
near half of it, a peak at it); the mat's response at a trace is the median of the traces whole periods away
(the trace itself left out, so a pipe's apex does not enter its own estimate); the chain searches the line with
that response taken out as well as the line itself (`run.interpret`). The bars are not read off the response:
halfway between two bars a few centimetres down both neighbours' flanks arrive together, brighter than either
top (a dipole radiates most towards the critical angle), so a period's brightest event lies half a spacing off
the bars and its earliest arrivals sit at the bars and halfway alike (FDTD mesh batch); the bars the line's own
hyperbolas show are reported as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from gprbot.gpr.chain.peaks import peak_offset
from gprbot.gpr.chain.prepare import PreparedBScan

FloatArray = NDArray[np.float64]

MIN_SPACING_M, MAX_SPACING_M = 0.04, 0.5  # bar spacings of slabs and walls
MIN_PERIODS = 4.0  # fewer periods along the line leave the median of the others too few copies to stand for it
MIN_PEAK = 0.5  # lateral autocorrelation of the envelope at the period
MIN_SWING = 0.3  # ... above its first trough: a line whose traces merely resemble their neighbours has none
NEIGHBOUR_PERIODS = 8  # copies each side: the response may change slowly along a long line
REFINE_STEPS = np.linspace(-0.02, 0.02, 9)  # relative spacings tried around the autocorrelation's peak
REFINE_DECIMATION = 4  # every 4th time sample is enough to tell the trial spacings apart
TOP_SHARE = 0.5  # the mat's top: the first time its response varies along the line this much of the most it does


@dataclass(frozen=True)
class Mat:
    """A mat's spacing (m), the strength of its periodicity, its response on the prepared grid (nx, ns), and the
    time (ns after transmit) of its top: below top_ns plus a period lies what the mat may hide."""

    spacing_m: float
    periodicity: float
    response: FloatArray
    top_ns: float


def _lateral_autocorrelation(a: FloatArray, lags: range) -> FloatArray:
    """Normalised correlation of the image with itself shifted by each lag (traces) along the line."""
    e = a - a.mean(axis=0, keepdims=True)
    return np.array([float(np.sum(e[:-k] * e[k:]) / (math.sqrt(float(np.sum(e[:-k] ** 2) * np.sum(e[k:] ** 2)))
                                                     + 1e-30)) for k in lags])


def lateral_period(envelope: FloatArray, data: FloatArray, dx_m: float) -> tuple[float, float] | None:
    """(spacing m, autocorrelation there) of the envelope's strongest lateral period past its first trough.

    The envelope does not care how a hand-tied bar's echo is phased (SS Mini File____002: its signed traces do not
    repeat, their envelopes do); but where the bars' flanks cross halfway between them, the envelope repeats at
    half the spacing, which the signed traces do not: so twice the period is taken when they repeat better there.
    """
    nx = envelope.shape[0]
    k_max = min(int(MAX_SPACING_M / dx_m), int(nx / MIN_PERIODS))
    if k_max < 3:
        return None
    ac = _lateral_autocorrelation(envelope, range(1, k_max + 1))
    troughs = np.nonzero((ac[1:-1] < ac[:-2]) & (ac[1:-1] <= ac[2:]))[0] + 1
    if not len(troughs):
        return None
    first = int(troughs[0])
    peak = first + int(np.argmax(ac[first:]))
    if peak >= len(ac) - 1 or ac[peak] < MIN_PEAK or ac[peak] - ac[first] < MIN_SWING:
        return None
    spacing = (peak + 1 + peak_offset(ac, peak)) * dx_m
    lag = peak + 1
    if 2 * lag <= nx / MIN_PERIODS:
        signed = _lateral_autocorrelation(data, range(lag, 2 * lag + 1, lag))
        if signed[1] >= MIN_PEAK and signed[1] > signed[0] + MIN_SWING:
            spacing *= 2.0
    return (spacing, float(ac[peak])) if spacing >= MIN_SPACING_M else None


def periodic_response(data: FloatArray, dx_m: float, spacing_m: float) -> FloatArray:
    """At every trace, the median of the traces whole periods away (up to NEIGHBOUR_PERIODS each side), interpolated
    along the line; the trace itself is left out."""
    nx = data.shape[0]
    at = np.arange(nx, dtype=np.float64)
    copies = []
    for k in range(-NEIGHBOUR_PERIODS, NEIGHBOUR_PERIODS + 1):
        if k == 0:
            continue
        pos = at + k * spacing_m / dx_m
        inside = (pos >= 0.0) & (pos <= nx - 1)
        lo = np.clip(np.floor(pos).astype(np.intp), 0, nx - 2)
        f = np.clip(pos - lo, 0.0, 1.0)[:, None]
        shifted = data[lo] * (1.0 - f) + data[lo + 1] * f
        copies.append(np.where(inside[:, None], shifted, np.nan))
    # The median of each trace's copies that lie on the line: sorted, the missing ones (NaN) go last, and the middle
    # of the ones there is picked (np.nanmedian does the same, several times slower).
    stack = np.sort(np.stack(copies), axis=0)
    have = np.isfinite(stack[:, :, 0]).sum(axis=0)
    lo_i = np.maximum(have - 1, 0) // 2
    hi_i = np.maximum(have, 1) // 2
    pick = np.arange(nx)
    out = 0.5 * (stack[lo_i, pick] + stack[hi_i, pick])
    out[have == 0] = 0.0
    return np.asarray(out, dtype=np.float64)


def find_mat(prep: PreparedBScan) -> Mat | None:
    """The line's mat, if its envelope repeats along the line with a bar spacing over enough periods."""
    found = lateral_period(prep.envelope, prep.data, prep.dx_m)
    if found is None or float(np.ptp(prep.x_m)) < MIN_PERIODS * found[0]:
        return None
    spacing, periodicity = found
    # The autocorrelation's peak is good to a fraction of a trace; over eight periods that fraction adds up, so
    # the spacing is refined to the one whose response leaves the least behind.
    trials = spacing * (1.0 + REFINE_STEPS)
    coarse = prep.data[:, ::REFINE_DECIMATION]  # the spacing, not the wavelet, is what is refined
    left = [float(np.sum((coarse - periodic_response(coarse, prep.dx_m, s)) ** 2)) for s in trials]
    i = int(np.argmin(left))
    step = float(REFINE_STEPS[1] - REFINE_STEPS[0])
    best = float(spacing * (1.0 + REFINE_STEPS[i] + step * peak_offset(-np.asarray(left), i)))
    response = periodic_response(prep.data, prep.dx_m, best)
    swing = response.std(axis=0)
    start = max(0, math.ceil(prep.t0_ns / prep.dt_ns))
    top = start + int(np.argmax(swing[start:] >= TOP_SHARE * float(swing[start:].max(initial=0.0))))
    return Mat(best, periodicity, response, top * prep.dt_ns - prep.t0_ns)


def without_mat(prep: PreparedBScan, mat: Mat) -> PreparedBScan:
    """The prepared line with the mat's response taken out (envelope recomputed; time zero, wavelet, noise kept)."""
    data = prep.data - mat.response
    return replace(prep, data=data, envelope=np.abs(signal.hilbert(data, axis=1)))
