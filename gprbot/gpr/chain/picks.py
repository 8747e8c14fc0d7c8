"""Stage 4a: picks along one hyperbola — the reflection's time on every trace of its flanks.

Tracking starts at the apex with the curve the semblance scan liked best, picks the envelope's peak
near the predicted time on each trace outwards (the same definition as time zero's). A flank ends after
two traces (and 2 cm) without a clear pick, at an earlier event, or at the aperture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.gpr.chain.candidates import ApexCandidate
from gprbot.gpr.chain.peaks import peak_offset
from gprbot.gpr.chain.prepare import PreparedBScan

FloatArray = NDArray[np.float64]

PICK_APERTURE_DEG = 60.0  # beyond, picks are mostly a neighbour's flank; (45° changed little on the FDTD dev half)
MIN_PICK_SNR = 3.0
MIN_PICK_RATIO = 0.06  # of the apex amplitude: weaker picks are another event or noise
MAX_MISSES = 2  # traces without a clear pick that end a flank, and at least GAP_M of the line
GAP_M = 0.02  # (a finely sampled line's flank is not ended by a few millimetres of interference)
MAX_EARLIER_PERIODS = 0.1


@dataclass(frozen=True)
class Picks:
    """Times (ns after transmit) of one hyperbola on the traces at x_m, their amplitudes, per-side counts."""

    candidate: ApexCandidate
    x_m: FloatArray
    t_ns: FloatArray
    amplitude: FloatArray
    left: int
    right: int


def pick_along(
    prep: PreparedBScan, cand: ApexCandidate, predicted_ns: FloatArray, depth_m: float, search_periods: float = 0.5
) -> Picks:
    """Pick the envelope's peak near `predicted_ns` on every column outwards from the apex (NaN: not predicted).

    The envelope, not a signed lobe, is followed: a flank's phase rotates with the angle and where two
    events overlap, but its envelope peak stays one peak. The search follows the data's drift from the
    prediction, so a rough first curve still leads along the flank.
    """
    nx, ns = prep.data.shape
    # The loop below runs for every trace of every flank: the line's constants and the predicted times
    # are Python floats, read once (the same values and the same IEEE arithmetic as numpy's scalars).
    dt, t0, dx, period = prep.dt_ns, prep.t0_ns, prep.dx_m, prep.period_ns
    env = prep.envelope
    predicted = np.asarray(predicted_ns, dtype=np.float64).tolist()
    search = max(2, round(search_periods * period / dt))
    floor = max(MIN_PICK_SNR * prep.noise, MIN_PICK_RATIO * cand.amplitude)
    reach = depth_m * math.tan(math.radians(PICK_APERTURE_DEG)) + dx
    earlier_by = MAX_EARLIER_PERIODS * period
    out: dict[int, tuple[float, float]] = {}
    counts = []
    max_misses = max(MAX_MISSES, math.ceil(GAP_M / dx - 1e-9))
    for step in (-1, 1):
        misses, found, shift, last = 0, 0, 0.0, -math.inf
        col = cand.column
        while 0 <= col < nx and misses < max_misses:
            if abs(col - cand.column) * dx > reach or not math.isfinite(predicted[col]):
                break
            on_curve = (predicted[col] + t0) / dt  # the predicted sample
            centre = round(on_curve + shift)
            lo, hi = max(0, centre - search), min(ns, centre + search + 1)
            if hi - lo < 3:
                break
            e = env[col, lo:hi]
            k = int(e.argmax())
            peak = float(e[k])
            s = lo + k + peak_offset(e, k)
            # Away from its apex a hyperbola only gets later: an earlier peak belongs to another event.
            earlier = s * dt < last - earlier_by
            if peak < floor or k in (0, hi - lo - 1) or earlier:
                misses += 1
            else:
                misses = 0
                last = max(last, s * dt)
                shift = s - on_curve
                out[col] = (s * dt - t0, peak)
                found += col != cand.column
            col += step
        counts.append(found)
    cols = np.array(sorted(out), dtype=np.intp)
    t = np.array([out[c][0] for c in cols])
    a = np.array([out[c][1] for c in cols])
    return Picks(cand, prep.x_m[cols], t, a, counts[0], counts[1])
