"""Stage 6: focused spots of the migrated image → the targets the hyperbola picks missed.

Picks follow one hyperbola trace by trace; where two pipes' flanks overlap (10 cm apart at 900 MHz), a
pipe lies under a rebar mesh, or a shallow top merges with the direct wave's tail, they wander and the
fit fails its gates. Migration at the line's velocity collapses each hyperbola to a spot wherever flanks
overlap, which is how a GPR analyst confirms a target. A spot is a target when it is a compact local
maximum of the image's envelope (a layer is flat, not compact), stands out of its own depth band, is not
explained by a detection already made, and is not an echo of a stronger spot: right under it within a
ringing or pipe-bottom delay, at twice its depth, or under the crossing flanks of two stronger neighbours.
Its top comes from the spot; its radius from a cylinder fit seeded there when that fit agrees with the
spot, else it is reported as not measured.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from gprbot.gpr.chain.candidates import ApexCandidate
from gprbot.gpr.chain.classify import MIN_FLANK_PICKS, ClassifiedDetection, reported_radius
from gprbot.gpr.chain.fit import R_MAX_M, CylinderFit
from gprbot.gpr.chain.geometry import cylinder_time
from gprbot.gpr.chain.peaks import peak_offset
from gprbot.gpr.chain.prepare import PreparedBScan
from gprbot.gpr.chain.reflectors import Reflector, fit_each, refit_each_at_velocity

FloatArray = NDArray[np.float64]

MIN_SPOT_FOCUS = 0.3  # of the 99th percentile of the image within a wavelength of the spot's depth (as `focused`)
MIN_SPOT_SHARE = 0.02  # of the image's brightest cell below the direct wave: weaker is migration noise
COMPACT_RATIO = 0.6  # a wavelength to one side the envelope falls below this share of the spot (a layer doesn't)
RINGING_WAVELENGTHS = 0.75  # an antenna rings about one and a half periods: that far under a spot is its echo
ECHO_X_M = 0.03
CROSSING_WAVELENGTHS = 0.5  # a V of crossing flanks migrates to a smear about this far around the crossing
MAX_SPOTS_PER_M = 10
EXPLAINED_M = 0.03  # a spot this near a detection's top (plus its radius in x) is that detection
EXPLAINED_TRACES = 1.5  # ... or this many trace steps along the line, where that is more
AGREE_PERIODS = 0.25  # a seeded fit whose top lies within this (as depth) of the spot measures its radius
MIN_SPOT_COHERENCE = 0.4  # semblance along the seeded fit: geology's clutter focuses to spots too, but
# its traces don't line up on a diffraction (FDTD dev and the real files: targets 0.42-0.79, clutter 0-0.33)


@dataclass(frozen=True)
class Spot:
    """A compact local maximum of the migrated envelope: x and top depth (m), brightness, share of its band."""

    x_m: float
    top_m: float
    brightness: float
    focus: float  # over the 99th percentile of the image within a wavelength of its depth
    column: int  # of the prepared grid


def find_spots(prep: PreparedBScan, env: NDArray[np.float32], z_m: FloatArray, v: float) -> tuple[Spot, ...]:
    """Compact spots of the migrated envelope (nz, nx) below the direct wave, strongest first."""
    if len(z_m) < 3 or env.shape[1] < 3:
        return ()
    e = np.asarray(env, dtype=np.float64)
    dz, wavelength = float(z_m[1] - z_m[0]), prep.wavelength_m(v)
    wz, wx = max(1, round(0.25 * wavelength / dz)), max(1, round(0.25 * wavelength / prep.dx_m))
    peaks = e == ndimage.maximum_filter(e, size=(2 * wz + 1, 2 * wx + 1), mode="nearest")
    # What migrates within the direct wave's tail is the antenna's own ringing; the image's lower edge is the
    # window's truncation. Neither is a target, nor the yardstick a target's brightness is judged against.
    eligible = (z_m >= 0.5 * v * 0.75 * prep.period_ns) & (z_m <= z_m[-1] - wavelength)
    peaks[~eligible, :] = False
    brightest = float(e[eligible].max(initial=0.0))
    band = max(1, round(wavelength / dz))
    row_level = np.percentile(e, 99.0, axis=1)
    band_level = ndimage.maximum_filter1d(row_level, 2 * band + 1, mode="nearest")
    peaks &= (e >= MIN_SPOT_FOCUS * band_level[:, None]) & (e >= MIN_SPOT_SHARE * brightest)
    side = max(2, round(wavelength / prep.dx_m))
    out = []
    for i, j in zip(*np.nonzero(peaks), strict=True):
        left, right = e[i, max(0, j - side)], e[i, min(e.shape[1] - 1, j + side)]
        if min(left, right) >= COMPACT_RATIO * e[i, j]:
            continue  # flat to both sides: a layer or the slab's bottom, not a diffraction's focus
        x = float(prep.x_m[j] + peak_offset(e[i, :], j) * prep.dx_m)
        top = float(z_m[i] + peak_offset(e[:, j], i) * dz)
        out.append(Spot(x, top, float(e[i, j]), float(e[i, j] / band_level[i]), int(j)))
    out.sort(key=lambda s: -s.brightness)
    return tuple(out[: max(4, round(MAX_SPOTS_PER_M * float(np.ptp(prep.x_m))))])


def is_echo_spot(spot: Spot, stronger: Sequence[tuple[float, float, float]], wavelength: float) -> bool:
    """Whether a spot is an echo of stronger targets (x, top, radius): ringing or a pipe's bottom under one,
    its surface multiple, or the crossing of two neighbours' flanks under and between them."""
    return _is_echo_of(spot, stronger, wavelength) or _under_crossing_flanks(spot, stronger, wavelength)


def _is_echo_of(spot: Spot, stronger: Sequence[tuple[float, float, float]], wavelength: float) -> bool:
    """Whether a spot lies under one of the targets within its ringing or bottom delay, or at twice its depth."""
    for x, top, radius in stronger:
        if spot.top_m <= top or abs(spot.x_m - x) > ECHO_X_M:  # a bottom or a ringing lies right under the centre
            continue
        if spot.top_m - top <= max(RINGING_WAVELENGTHS * wavelength, 6.0 * radius):
            return True
        if abs(spot.top_m - 2.0 * top) <= 0.15 * top + 0.005:
            return True
    return False


def _crossing(xl: FloatArray, zl: FloatArray, xr: FloatArray, zr: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Where pairs of point diffractors' zero-offset curves cross: along-track x and the depth it migrates near.

    Every pair is bisected at once (elementwise: each pair's steps are those it would take alone).
    """
    lo, hi = xl, xr
    for _ in range(40):  # the difference of the two distances grows monotonically from xl to xr
        mid = 0.5 * (lo + hi)
        nearer_left = np.hypot(mid - xl, zl) < np.hypot(mid - xr, zr)
        lo, hi = np.where(nearer_left, mid, lo), np.where(nearer_left, hi, mid)
    x = 0.5 * (lo + hi)
    return x, np.hypot(x - xl, zl)


def _under_crossing_flanks(spot: Spot, stronger: Sequence[tuple[float, float, float]], wavelength: float) -> bool:
    """Whether a spot lies where two neighbours' flanks cross (a V, deeper than both tops, between them)."""
    left = [(x, top) for x, top, _ in stronger if x < spot.x_m and top < spot.top_m]
    right = [(x, top) for x, top, _ in stronger if x > spot.x_m and top < spot.top_m]
    if not left or not right:
        return False
    (xl, tl), (xr, tr) = np.array(left).T, np.array(right).T
    x, z = _crossing(xl[:, None], tl[:, None], xr[None, :], tr[None, :])  # (left, right): every pair
    near = (np.abs(spot.x_m - x) <= ECHO_X_M) & (np.abs(spot.top_m - z) <= CROSSING_WAVELENGTHS * wavelength)
    return bool(near.any())


def spot_candidate(prep: PreparedBScan, spot: Spot, v: float) -> ApexCandidate | None:
    """The apex candidate a point at the spot would give (to seed a cylinder fit there)."""
    t = float(cylinder_time(prep.x_m[spot.column: spot.column + 1], spot.x_m, spot.top_m, 0.0, v,
                            prep.antenna_height_m, prep.tx_rx_offset_m)[0])
    sample = (t + prep.t0_ns) / prep.dt_ns
    ns = prep.data.shape[1]
    if not 0 <= sample < ns - 1:
        return None
    s = round(sample)
    amplitude = float(prep.envelope[spot.column, s])
    half = max(1, round(0.5 * prep.period_ns / prep.dt_ns))
    lo, hi = max(0, s - half), min(ns, s + half + 1)
    lobe = lo + int(np.argmax(np.abs(prep.data[spot.column, lo:hi])))
    polarity = 1.0 if prep.data[spot.column, lobe] >= 0 else -1.0
    return ApexCandidate(spot.column, sample, t, amplitude, amplitude / prep.noise, polarity)


def _seeded_all(prep: PreparedBScan, spots: Sequence[Spot], v: float) -> list[Reflector | None]:
    """Each spot's cylinder fit seeded there, kept when it lands on the spot (its radius is then measured)."""
    cands = [spot_candidate(prep, spot, v) for spot in spots]
    index = [k for k, c in enumerate(cands) if c is not None]
    fitted = fit_each(prep, [c for c in cands if c is not None])
    present = [(k, r) for k, r in zip(index, fitted, strict=True) if r is not None]
    refitted = refit_each_at_velocity(prep, [r for _, r in present], v)
    agree = 0.5 * v * AGREE_PERIODS * prep.period_ns
    out: list[Reflector | None] = [None] * len(spots)
    for (k, _), r in zip(present, refitted, strict=True):
        spot = spots[k]
        if r is not None and r.fit is not None and abs(r.fit.top_m - spot.top_m) <= agree \
                and abs(r.fit.x0_m - spot.x_m) <= agree:
            out[k] = r
    return out


def _spot_detection(prep: PreparedBScan, spot: Spot, seeded: Reflector | None, v: float) -> ClassifiedDetection | None:
    """A detection at a spot whose seeded fit agrees with it and lines the traces up; None otherwise."""
    if seeded is None or seeded.fit is None or seeded.coherence < MIN_SPOT_COHERENCE:
        return None
    # Both flanks must be there (a layer's end or a dipping event has one); the spot, not the misfit,
    # is the evidence here — overlapping flanks make picks loose (FDTD dev: true 0.07-0.64 periods rms).
    if min(seeded.picks.left, seeded.picks.right) < MIN_FLANK_PICKS or seeded.fit.radius_m >= 0.95 * R_MAX_M:
        return None
    f = seeded.fit
    # The spot places the top (migration is robust where flanks overlap); the fit measures the radius.
    radius, sigma, supported = reported_radius(f)
    fit = CylinderFit(spot.x_m, spot.top_m, radius, v, f.sigma_x0_m, f.sigma_top_m, sigma, 0.0, f.rms_ns, f.n_picks)
    contrast: Literal["slower", "faster"] = "faster" if seeded.candidate.polarity == prep.direct_polarity else "slower"
    confidence = float(min(1.0, spot.focus) * min(1.0, seeded.coherence / 0.5)
                       * (1.0 - np.exp(-seeded.candidate.snr / 15.0)))
    return ClassifiedDetection(fit.x0_m, fit.depth_m, fit.radius_m, fit.sigma_radius_m, supported, "pipe",
                               contrast, confidence, fit, seeded, found_by="migrated spot",
                               radius_source="fit" if supported else "none")


def spot_detections(prep: PreparedBScan, spots: Sequence[Spot], detections: Sequence[ClassifiedDetection],
                    v: float) -> tuple[ClassifiedDetection, ...]:
    """Detections at the spots no detection explains and that are no echo of a stronger target."""
    wavelength = prep.wavelength_m(v)
    known = [(d.x_m, d.fit.top_m, _fitted_radius(d)) for d in detections]
    # A spot's x and a fit's apex each sit to within about a trace of the truth: on a coarse line (the SU trench,
    # 4 cm traces) one target's spot and fit lie 5 cm apart, and were reported twice.
    along = max(EXPLAINED_M, EXPLAINED_TRACES * prep.dx_m)

    def open_spot(spot: Spot) -> bool:
        explained = any(abs(spot.x_m - x) <= along + r and abs(spot.top_m - top) <= EXPLAINED_M
                        for x, top, r in known)
        return not explained and not is_echo_spot(spot, known, wavelength)

    # Shallow first: an echo is judged after its primary. The seeded fits of every spot still open are
    # made in one batch (one fit per spot costs a batched fit's overhead each); `known` only grows, so a
    # spot closed now stays closed.
    todo = [s for s in sorted(spots, key=lambda s: s.top_m) if open_spot(s)]
    out: list[ClassifiedDetection] = []
    for spot, seeded in zip(todo, _seeded_all(prep, todo, v), strict=True):
        if not open_spot(spot):
            continue
        det = _spot_detection(prep, spot, seeded, v)
        if det is None:
            continue
        known.append((det.x_m, det.fit.top_m, _fitted_radius(det)))
        out.append(det)
    return tuple(out)


def _fitted_radius(d: ClassifiedDetection) -> float:
    """The radius the detection's curve was fitted with (kept for echo windows even where not reported)."""
    return d.reflector.fit.radius_m if d.reflector.fit is not None else d.radius_m


def without_echoes_of(detections: Sequence[ClassifiedDetection], tops: Sequence[ClassifiedDetection],
                      wavelength: float) -> tuple[ClassifiedDetection, ...]:
    """The detections less those that are echoes of one of `tops` (its ringing, bottom or multiple): a
    hyperbola-path detection can be the echo of a top that only the migrated image resolved."""
    primaries = [(t.x_m, t.fit.top_m, _fitted_radius(t)) for t in tops]
    return tuple(d for d in detections if not _is_echo_of(Spot(d.x_m, d.fit.top_m, 0.0, 0.0, 0), primaries, wavelength))
