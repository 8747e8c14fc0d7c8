"""Stage 3: the wave velocity from many diffractions at once, with its uncertainty and how it was found.

On one hyperbola radius and velocity trade off (a larger pipe at a lower velocity has nearly the same
curve over the usable aperture), so fitting curves to picks gives a poor velocity: on the FDTD dev half
free fits were off by 8-70 %. At the right velocity a diffraction, a bar or a pipe's top collapses into
its reflector — a point or a short arc — and the migrated amplitude peaks there. So each hyperbola is
migrated locally (a window around its apex) at a ladder of trial velocities, coarse then fine; the velocity
where its peak amplitude is highest is its vote. The line's velocity is the weighted median of the votes
(weights: how sharply each peaks and how strong it is). Near the apex the focus shares the trade-off after
all (a cylinder focuses as a point at v·√(1 + R/d): validation/README.md), so the reported uncertainty is
the weighted spread of the votes over √n (never below a quarter step) together with what the voters'
unknown radii allow (`radius_trade_off`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.gpr.chain.geometry import cylinder_time
from gprbot.gpr.chain.peaks import peak_offset
from gprbot.gpr.chain.prepare import PreparedBScan
from gprbot.gpr.chain.reflectors import Reflector

FloatArray = NDArray[np.float64]

V_MIN, V_MAX = 0.05, 0.25  # m/ns: wet clay … dry sand; concrete is 0.08-0.15
COARSE_STEPS = 13
FINE_STEPS = 5
APERTURE_DEG = 50.0
WINDOW_X_M = 0.05
MAX_VOTERS = 6
MIN_FLANK = 3
ECHO_X_M = 0.03  # a later hyperbola this close under a stronger one is its echo
MULTIPLE_TIME_TOLERANCE = 0.15  # of twice the primary's apex time
MIN_CONTRAST = 1.15  # a focus curve whose peak is not this far above its ends says nothing
SHALLOW_M = 0.06  # FDTD dev half: tops above ~5 cm voted 20-50 % off
FULL_SPAN_TRACES = 25  # traces within the aperture for a vote at full weight
# The radius of the larger utility pipes (100 mm across), for the trade-off a vote's unknown radius brings. FDTD
# dev half: with it 21 of 33 line velocities lie within 1 sigma and 29 within 2; without it 17 and 20.
RADIUS_SCALE_M = 0.05


@dataclass(frozen=True)
class Vote:
    """One hyperbola's vote: its apex (m along the line, ns after time zero), the velocity it focuses at, its weight."""

    x_m: float
    t_ns: float
    v: float
    weight: float


@dataclass(frozen=True)
class VelocityEstimate:
    """The velocity (m/ns), its 1-sigma uncertainty, the number of diffractions used, and how."""

    v: float
    sigma: float
    n_used: int
    method: str
    shallow: bool = False  # only targets within SHALLOW_M of the surface voted: the antenna geometry rules there
    # the relative 1-sigma that the voters' unknown radii add (`radius_trade_off`); `sigma` is the votes' agreement
    trade_off: float = 0.0
    # each hyperbola's own vote, so that an analyst sees whether they agree (a few votes in two clusters make a
    # median that jumps between them: the SU trench line read 0.147 or 0.169 m/ns with its trace step 0.15 % apart)
    votes: tuple[Vote, ...] = ()

    @property
    def uncertainty(self) -> float:
        """The velocity's 1-sigma (m/ns) as reported: the votes' agreement and their radii's trade-off together."""
        return self.v * math.hypot(self.sigma / self.v, self.trade_off)


def radius_trade_off(top_m: FloatArray, weights: FloatArray) -> float:
    """The relative 1-sigma a line's velocity carries because its voters' radii are unknown.

    A cylinder of radius R with its top at depth d focuses as a point at v·√(1 + R/d) (validation/README.md,
    the velocity votes), so a vote can be fast by up to that factor; half its log-range for a pipe of
    RADIUS_SCALE_M, at the typical voter's depth, is the 1-sigma. It does not shrink with more votes: every
    voter's radius is unknown and each leans the same way.
    """
    return weighted_median(0.5 * np.log1p(RADIUS_SCALE_M / np.maximum(top_m, 0.005)), weights)


def focus(prep: PreparedBScan, column: int, apex_t_ns: float, velocities: FloatArray) -> FloatArray:
    """Peak Kirchhoff-migrated amplitude near a hyperbola's apex at each trial velocity.

    The image covers ±WINDOW_X_M along the line around the apex and the depths where the apex time puts
    the top at that velocity; each image point sums the traces along its diffraction curve within the
    aperture with Kirchhoff's obliquity and spreading weights and a cosine taper (as
    `migration.kirchhoff_migrate`, whose window it computes in one vectorised gather).
    """
    nx, ns = prep.data.shape
    half = max(2, round(WINDOW_X_M / prep.dx_m))
    tan_ap = math.tan(math.radians(APERTURE_DEG))
    v = np.asarray(velocities, dtype=np.float64)[:, None, None]  # (velocities, lags, depths)
    offsets = np.arange(-0.03, 0.04, 0.003)
    z = np.maximum(0.002, 0.5 * v * apex_t_ns + offsets[None, None, :])
    reach = math.ceil(float(z.max()) * tan_ap / prep.dx_m)
    lags = np.arange(-reach, reach + 1)
    # A common-offset curve is even in the lag (the two legs swap), and so are its weights: they are made
    # for the lags ≥ 0 and mirrored.
    horiz = np.asarray(np.arange(reach + 1)[None, :, None] * prep.dx_m, dtype=np.float64)
    times = cylinder_time(horiz, 0.0, z, 0.0, v, prep.antenna_height_m, prep.tx_rx_offset_m)
    sample = (times + prep.t0_ns) / prep.dt_ns
    ratio = horiz / (z * tan_ap)
    taper = np.where(ratio <= 0.7, 1.0, 0.5 * (1.0 + np.cos(np.pi * np.clip(ratio - 0.7, 0.0, 0.3) / 0.3)))
    r = np.hypot(horiz, z)
    weight = np.where((ratio <= 1.0) & (sample >= 0.0) & (sample < ns - 1), taper * (z / r) / np.sqrt(r), 0.0)
    s = np.clip(sample, 0.0, ns - 1.001)
    i0 = s.astype(np.intp)
    frac = s - i0
    # The linear interpolation folded into the weights; single precision halves the gathers' memory traffic
    # (a peak's position, not its last digits, is what the vote needs).
    w_lo, w_hi = _mirrored((weight * (1.0 - frac)).astype(np.float32)), _mirrored((weight * frac).astype(np.float32))
    # Traces beyond the line's ends are zeros: pad by the reach, then one flat index serves every gather.
    pairs = _sample_pairs(prep.data32, reach)
    at_first = (lags + reach)[None, :, None] * ns + _mirrored(i0)  # flat index for the window's first column
    cols = np.arange(max(0, column - half), min(nx, column + half + 1))
    out = np.zeros(len(velocities))
    # Each velocity gathers only the lags its own aperture reaches (a slow velocity's image is shallow
    # and narrow; outside its reach the weights are zero anyway).
    own = np.ceil(z.max(axis=(1, 2)) * tan_ap / prep.dx_m).astype(np.intp)
    for i, k in enumerate(np.minimum(own, reach)):
        lags_i = slice(reach - k, reach + k + 1)
        idx = at_first[i, lags_i][None] + (cols * ns)[:, None, None]  # (columns, lags, depths)
        both = pairs[idx].view(np.float32)  # each sample and the next, interleaved along the depths
        # einsum adds the lags one after another, as sum(axis=1) does, in one loop instead of one per lag.
        image = np.einsum("clz->cz", both[..., 0::2] * w_lo[i, lags_i] + both[..., 1::2] * w_hi[i, lags_i])
        out[i] = np.abs(image).max()
    return out


def _mirrored(half: NDArray[Any]) -> NDArray[Any]:
    """An array over the lags ≥ 0 (axis 1) extended to the negative lags by symmetry."""
    return np.concatenate([half[:, :0:-1], half], axis=1)


def _sample_pairs(data: NDArray[np.float32], reach: int) -> NDArray[np.float64]:
    """Every sample with the next one on its trace, as one 8-byte item (flat, traces padded by `reach` zero ones).

    The interpolation reads both; gathering them as one item halves the gathers. The last sample of a
    trace is never the first of a pair (the interpolation stops one short), so its partner is a zero.
    """
    nx, ns = data.shape
    pairs = np.zeros((nx + 2 * reach, ns, 2), dtype=np.float32)
    pairs[reach : reach + nx, :, 0] = data
    pairs[reach : reach + nx, :-1, 1] = data[:, 1:]
    return pairs.view(np.float64).ravel()


def _peak(curve: FloatArray, velocities: FloatArray) -> float | None:
    """Sub-step velocity of the curve's interior maximum (log-spaced ladder); None at an end."""
    i = int(np.argmax(curve))
    if i in (0, len(curve) - 1):
        return None
    frac = peak_offset(curve, i)
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
    # A shallow hyperbola spans few traces within the aperture: its focus hardly tells velocities apart
    # (FDTD dev half: tops above ~5 cm voted 20-50 % off, deeper ones within 5 %).
    top = 0.5 * v * r.candidate.t_ns
    span = 2.0 * top * math.tan(math.radians(APERTURE_DEG)) / prep.dx_m + 1.0
    return v, math.log(contrast) * math.log1p(r.candidate.snr) * min(1.0, span / FULL_SPAN_TRACES) ** 2


def _primaries(prep: PreparedBScan, strongest_first: Sequence[Reflector]) -> list[Reflector]:
    """The hyperbolas that are not echoes: a later event right under a stronger one (a pipe's bottom, its
    ringing or surface multiple) keeps the primary's curvature at a later time and so votes far too slow
    (FDTD dev: 0.057 m/ns under a 0.12 m/ns water pipe, outvoting it)."""
    # Judged earliest first: a water-filled pipe's bottom echo can be brighter than its top (FDTD dev:
    # 0.46x the true velocity, voting first), yet it is the later event under it.
    kept: list[Reflector] = []
    for r in sorted(strongest_first, key=lambda r: r.candidate.t_ns):
        x, t = prep.x_m[r.candidate.column], r.candidate.t_ns
        if not any(_echo_of(x, t, prep.x_m[k.candidate.column], k.candidate.t_ns) for k in kept):
            kept.append(r)
    primary = {id(r) for r in kept}
    return [r for r in strongest_first if id(r) in primary]  # strongest first again


def _echo_of(x: float, t: float, x_primary: float, t_primary: float) -> bool:
    """Whether an apex (x, t) is an echo of a stronger one: later right under it, or at about twice its
    time near it (the surface multiple, whose apex a neighbour's flank can pull a few centimetres aside)."""
    dx = abs(x - x_primary)
    under = dx <= ECHO_X_M and t > t_primary
    multiple = dx <= 2.0 * ECHO_X_M and abs(t / max(t_primary, 1e-9) - 2.0) <= MULTIPLE_TIME_TOLERANCE
    return under or multiple


def weighted_median(values: FloatArray, weights: FloatArray) -> float:
    """The value at which the weights, summed in the values' order, reach half their total."""
    order = np.argsort(values)
    cum = np.cumsum(np.asarray(weights, dtype=np.float64)[order])
    return float(np.asarray(values)[order][np.searchsorted(cum, 0.5 * cum[-1])])


def voters(prep: PreparedBScan, reflectors: Sequence[Reflector]) -> list[Reflector]:
    """The hyperbolas that vote: two-sided primaries, those that stand out most of their own time first."""
    two_sided = [r for r in reflectors
                 if min(r.picks.left, r.picks.right) >= max(MIN_FLANK, 0.25 * max(r.picks.left, r.picks.right))]
    two_sided.sort(key=lambda r: -r.candidate.snr)
    # Echoes are judged against the strongest first; the voters are the hyperbolas that stand out most of
    # their own time: on a long field line the bright near-surface zone otherwise fills every seat (a trench
    # line: the one of its six near-surface voters that focused gave 0.227 m/ns; the fill's published velocity is
    # 0.165, and the deep diffractors now give 0.169).
    return sorted(_primaries(prep, two_sided), key=lambda r: -r.candidate.contrast)[:MAX_VOTERS]


def estimate_velocity(prep: PreparedBScan, reflectors: Sequence[Reflector]) -> VelocityEstimate | None:
    """The velocity the hyperbolas' migration focus agrees on; None when no hyperbola focuses."""
    chosen = voters(prep, reflectors)
    cast = [(r, x) for r, x in ((r, vote(prep, r)) for r in chosen) if x is not None]
    votes = [x for _, x in cast]
    if not votes:
        return None
    v, w = np.array([x[0] for x in votes]), np.array([x[1] for x in votes])
    median = weighted_median(v, w)
    spread = float(np.sqrt(np.sum(w * np.log(v / median) ** 2) / np.sum(w)))
    step = math.log(V_MAX / V_MIN) / (COARSE_STEPS - 1) / (FINE_STEPS - 1) * 2.0
    n = len(votes)
    sigma_rel = max(spread / math.sqrt(n), 0.25 * step) if n > 1 else max(spread, step)
    how = (f"migration focus of {n} diffraction hyperbolas (weighted median)" if n > 1
           else "the migration focus of one diffraction hyperbola")
    deepest = max(0.5 * median * r.candidate.t_ns for r in chosen)
    listed = tuple(Vote(float(prep.x_m[r.candidate.column]), r.candidate.t_ns, x[0], x[1]) for r, x in cast)
    tops = np.array([0.5 * x[0] * r.candidate.t_ns for r, x in cast])
    return VelocityEstimate(median, median * sigma_rel, n, how, shallow=deepest < SHALLOW_M, votes=listed,
                            trade_off=radius_trade_off(tops, w))
