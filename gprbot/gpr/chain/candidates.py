"""Stage 2: apex candidates — where an event arrives earliest along the line (a hyperbola's top).

A hyperbola's apex is where its arrival time is smallest, not where it is brightest: a dipole at the
surface radiates most strongly near the critical angle, so FDTD flanks of a 4 cm pipe are twice as
bright as its top. Every column's envelope peaks (local maxima in time that stand out of the noise)
are events; an event is an apex candidate when, a few centimetres to either side, the same event (the
nearest peak within half a period) arrives no earlier. Neighbouring candidates on one flat top are
merged into the earliest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from gprbot.gpr.chain.peaks import peak_offset
from gprbot.gpr.chain.prepare import PreparedBScan

SNR_MIN = 6.0  # envelope over the noise's standard deviation
DYNAMIC_RANGE = 0.01  # events weaker than this fraction of the strongest are numerical dust or ringing
MAX_CANDIDATES = 24  # on a line up to 2 m; longer lines get CANDIDATES_PER_M
CANDIDATES_PER_M = 12
MAX_CANDIDATES_LINE = 400
APEX_TEST_M = 0.03  # neighbours this far either side must see the event no earlier
APEX_EARLIER_PERIODS = 0.05


@dataclass(frozen=True)
class ApexCandidate:
    """An event's earliest point: grid column, fractional sample, time after transmit, amplitude, snr."""

    column: int
    sample: float
    t_ns: float
    amplitude: float
    snr: float
    polarity: float  # sign of the largest lobe at the apex
    contrast: float = 0.0  # envelope over its median along the line at the same time (`lateral_level`)


def _events(prep: PreparedBScan) -> tuple[np.ndarray, np.ndarray]:
    """Boolean (nx, ns) map of envelope peaks in time above the threshold, and the threshold."""
    env = prep.envelope
    half_t = max(1, round(0.25 * prep.period_ns / prep.dt_ns))
    peaks = env == ndimage.maximum_filter1d(env, 2 * half_t + 1, axis=1, mode="nearest")
    first = int(np.ceil((prep.t0_ns + 0.5 * prep.period_ns) / prep.dt_ns))
    peaks[:, : max(first, 0)] = False
    peaks[:, env.shape[1] - half_t :] = False
    threshold = max(SNR_MIN * prep.noise, DYNAMIC_RANGE * float(env[:, max(first, 0):].max(initial=0.0)))
    return peaks & (env > threshold), np.array(threshold)


def _earliest(events: np.ndarray, cols: np.ndarray, rows: np.ndarray, k: int, half: int,
              tolerance: float) -> np.ndarray:
    """For every event (cols[i], rows[i]): whether it arrives no earlier than its continuation k columns to each
    side — the nearest event there within `half` samples (the earlier of two equally near); where the event
    does not continue (a line end, or it fades) there is no evidence against it."""
    nx, ns = events.shape
    ec, er = np.nonzero(events)
    keys = ec * ns + er  # sorted: by column, then row
    ok = np.ones(len(cols), dtype=bool)
    if not len(keys):
        return ok
    for side in (-k, k):
        col = cols + side
        query = col * ns + rows
        at = np.searchsorted(keys, query)
        above = keys[np.minimum(at, len(keys) - 1)]
        below = keys[np.maximum(at - 1, 0)]
        up = (at < len(keys)) & (above // ns == col) & (above - query <= half)
        down = (at > 0) & (below // ns == col) & (query - below <= half)
        nearer_is_earlier = down & (~up | (query - below <= above - query))
        ok &= ~((col >= 0) & (col < nx) & nearer_is_earlier & (query - below > tolerance))
    return ok


def lateral_level(env: np.ndarray, noise: float) -> np.ndarray:
    """Per time sample, the envelope's median along the line plus the noise: what a candidate's contrast is
    measured against (a hyperbola's top stands out of its row; a bright band that every trace shares, the
    surface zone or a layer, does not)."""
    return np.asarray(np.median(env, axis=0) + noise)


def apex_candidates(prep: PreparedBScan) -> tuple[ApexCandidate, ...]:
    """Apex candidates after the direct wave, strongest first (at most MAX_CANDIDATES)."""
    events, _ = _events(prep)
    env = prep.envelope
    k = max(2, round(APEX_TEST_M / prep.dx_m))
    half = max(1, round(0.5 * prep.period_ns / prep.dt_ns))
    tolerance = APEX_EARLIER_PERIODS * prep.period_ns / prep.dt_ns
    cols, rows = np.nonzero(events)
    apex = _earliest(events, cols, rows, k, half, tolerance)
    cols, rows = cols[apex], rows[apex]
    # One candidate per top: the earliest, then none within k columns and a quarter period of it.
    picked: list[tuple[int, int]] = []
    quarter = max(1, half // 2)
    taken = np.zeros(env.shape, dtype=bool)  # cells within k columns and a quarter period of a pick
    for i in np.lexsort((-env[cols, rows], rows)):
        c, r = int(cols[i]), int(rows[i])
        if not taken[c, r]:
            picked.append((c, r))
            taken[max(0, c - k) : c + k + 1, max(0, r - quarter) : r + quarter + 1] = True
    picked.sort(key=lambda cr: -env[cr[0], cr[1]])
    limit = min(MAX_CANDIDATES_LINE, max(MAX_CANDIDATES, round(CANDIDATES_PER_M * float(np.ptp(prep.x_m)))))
    level = lateral_level(env, prep.noise)  # only the kept candidates' contrasts are needed, not the whole image's
    out = []
    ns = env.shape[1]
    for c, r in picked[:limit]:
        frac = peak_offset(env[c], r)
        lo, hi = max(0, r - half), min(ns, r + half + 1)
        lobe = lo + int(np.argmax(np.abs(prep.data[c, lo:hi])))
        out.append(ApexCandidate(c, r + frac, (r + frac) * prep.dt_ns - prep.t0_ns, float(env[c, r]),
                                 float(env[c, r] / prep.noise), 1.0 if prep.data[c, lobe] >= 0 else -1.0,
                                 float(env[c, r] / level[r])))
    return tuple(out)
