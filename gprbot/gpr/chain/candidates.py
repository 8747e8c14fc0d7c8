"""Stage 2: apex candidates — local maxima of the B-scan's envelope that stand out of the noise.

A hyperbola's apex is the brightest point of its curve along the line and the peak of its wavelet in
time, so it is a local maximum of the envelope over about one Fresnel-zone width and one period. Flanks
and ringing phases are not (they fall off towards the apex or merge into its envelope).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from gprbot.gpr.chain.prepare import PreparedBScan

SNR_MIN = 6.0  # envelope over the noise's standard deviation
DYNAMIC_RANGE = 0.004  # candidates weaker than this fraction of the strongest are numerical dust
MAX_CANDIDATES = 40
APEX_TEST_M = 0.03  # neighbours this far either side must see the event later
APEX_EARLIER_PERIODS = 0.08


@dataclass(frozen=True)
class ApexCandidate:
    """A local envelope maximum: grid column, fractional sample, time after transmit, amplitude, snr."""

    column: int
    sample: float
    t_ns: float
    amplitude: float
    snr: float
    polarity: float  # sign of the largest lobe at the apex


def _is_apex(prep: PreparedBScan, col: int, row: int) -> bool:
    """Whether the envelope peak at (col, row) is a hyperbola's top: on both sides its event arrives later.

    On a flank, the event is earlier on the side towards its apex; at an apex it is later (or level) on
    both. The event on a neighbouring column is the envelope's peak within half a period.
    """
    nx, ns = prep.envelope.shape
    k = max(2, round(APEX_TEST_M / prep.dx_m))
    half = max(1, round(0.5 * prep.period_ns / prep.dt_ns))
    lo, hi = max(0, row - half), min(ns, row + half + 1)
    tolerance = APEX_EARLIER_PERIODS * prep.period_ns / prep.dt_ns
    for side in (col - k, col + k):
        if 0 <= side < nx and lo + int(np.argmax(prep.envelope[side, lo:hi])) < row - tolerance:
            return False
    return True


def apex_candidates(prep: PreparedBScan, x_window_m: float = 0.06) -> tuple[ApexCandidate, ...]:
    """Local maxima of the envelope after the direct wave, strongest first (at most MAX_CANDIDATES)."""
    env = prep.envelope
    nx, ns = env.shape
    half_x = max(1, round(0.5 * x_window_m / prep.dx_m))
    half_t = max(1, round(0.75 * prep.period_ns / prep.dt_ns))
    peaks = env == ndimage.maximum_filter(env, size=(2 * half_x + 1, 2 * half_t + 1), mode="nearest")
    first = int(np.ceil((prep.t0_ns + 0.5 * prep.period_ns) / prep.dt_ns))
    peaks[:, : max(first, 0)] = False
    peaks[:, ns - half_t :] = False
    threshold = max(SNR_MIN * prep.noise, DYNAMIC_RANGE * float(env.max()))
    cols, rows = np.nonzero(peaks & (env > threshold))
    order = np.argsort(-env[cols, rows])
    out: list[ApexCandidate] = []
    for c, r in zip(cols[order], rows[order], strict=True):
        if len(out) >= MAX_CANDIDATES:
            break
        if not _is_apex(prep, int(c), int(r)):
            continue
        a, b, d = (env[c, r - 1], env[c, r], env[c, r + 1]) if 0 < r < ns - 1 else (0.0, 1.0, 0.0)
        denom = a - 2.0 * b + d
        frac = 0.0 if denom == 0 else float(np.clip(0.5 * (a - d) / denom, -0.5, 0.5))
        lo, hi = max(0, r - half_t), min(ns, r + half_t + 1)
        lobe = lo + int(np.argmax(np.abs(prep.data[c, lo:hi])))
        out.append(ApexCandidate(int(c), r + frac, (r + frac) * prep.dt_ns - prep.t0_ns, float(env[c, r]),
                                 float(env[c, r] / prep.noise), 1.0 if prep.data[c, lobe] >= 0 else -1.0))
    return tuple(out)
