"""Stage 4: apex candidates → fitted reflectors (one per hyperbola), each with its picks and its fits.

Every candidate is scanned (semblance over velocity and radius) for a first curve, picked along it and
fitted with the velocity free, all candidates in one batch; candidates whose fits land on one target (a
flank, a ringing phase of a stronger one) are merged into the strongest, which is picked again along its
fitted curve and refitted.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from gprbot.gpr.chain.candidates import ApexCandidate
from gprbot.gpr.chain.fit import CylinderFit, fit_cylinders
from gprbot.gpr.chain.geometry import cylinder_time
from gprbot.gpr.chain.picks import Picks, pick_along
from gprbot.gpr.chain.prepare import PreparedBScan
from gprbot.gpr.chain.semblance import (
    APERTURE_DEG,
    TravelTable,
    aperture_mask,
    centre_depths,
    curve_samples,
    semblance,
    travel_table,
)

FloatArray = NDArray[np.float64]

TRIAL_VELOCITIES = np.geomspace(0.04, 0.25, 24)
TRIAL_RADII = np.array([0.0, 0.012, 0.03, 0.06])
SAME_TARGET_M = 0.03
SAME_TARGET_RADIUS_CAP_M = 0.02
SCAN_BATCH = 8  # candidates per semblance gather


@dataclass(frozen=True)
class Reflector:
    """One hyperbola: apex candidate, picks, free-velocity fit, scan coherence, and the fit at the line's velocity."""

    candidate: ApexCandidate
    picks: Picks
    free_fit: CylinderFit
    coherence: float
    fit: CylinderFit | None = None  # at the line's velocity (set by `refit_at_velocity`)


def line_table(prep: PreparedBScan, candidates: Sequence[ApexCandidate]) -> TravelTable | None:
    """The trial-velocity travel-time table deep and wide enough for the line's deepest candidate."""
    if not candidates:
        return None
    z_max = 0.5 * float(TRIAL_VELOCITIES.max()) * max(c.t_ns for c in candidates) + float(TRIAL_RADII.max()) + 0.05
    max_lag = int(min(prep.data.shape[0] - 1, np.ceil(z_max * np.tan(np.radians(APERTURE_DEG)) / prep.dx_m)))
    return travel_table(prep, TRIAL_VELOCITIES, z_max, max(2, max_lag))


def _first_curves(
    prep: PreparedBScan, table: TravelTable, cands: Sequence[ApexCandidate]
) -> list[tuple[float, float, float, float] | None]:
    """(v, radius, centre depth, coherence) of each candidate's best semblance over the trial grid."""
    out: list[tuple[float, float, float, float] | None] = []
    half = max(1, round(0.25 * prep.period_ns / prep.dt_ns))
    for first in range(0, len(cands), SCAN_BATCH):  # a few candidates at a time bounds the gather's memory
        batch = cands[first : first + SCAN_BATCH]
        zc = centre_depths(table, np.array([c.t_ns for c in batch]), TRIAL_RADII)  # (batch, nv, nr)
        samples = curve_samples(table, zc, TRIAL_RADII, prep.t0_ns, prep.dt_ns)
        columns = np.array([c.column for c in batch], dtype=np.intp)[:, None, None]
        s = semblance(prep, columns, samples, table.lag_traces, aperture_mask(table, zc, prep.dx_m), half)
        s = np.where(np.isfinite(zc), s, 0.0)
        for k in range(len(batch)):
            i, j = np.unravel_index(int(np.argmax(s[k])), s[k].shape)
            ok = np.isfinite(zc[k, i, j])
            out.append((float(TRIAL_VELOCITIES[i]), float(TRIAL_RADII[j]), float(zc[k, i, j]), float(s[k, i, j]))
                       if ok else None)
    return out


def _same_target(a: CylinderFit, b: CylinderFit) -> bool:
    """Whether two fits describe one target (their tops within a few centimetres)."""
    near = abs(a.x0_m - b.x0_m) <= SAME_TARGET_M + min(max(a.radius_m, b.radius_m), SAME_TARGET_RADIUS_CAP_M)
    return near and abs(a.top_m - b.top_m) <= SAME_TARGET_M


def _pick_all(
    prep: PreparedBScan, cands: Sequence[ApexCandidate], curves: Sequence[tuple[float, float, float, float]],
    search_periods: float,
) -> list[Picks]:
    """Picks of every candidate along its curve (x0 = the candidate's column) at (v, radius, centre depth)."""
    if not cands:
        return []
    # Every curve timed in one call (a row each): the times are elementwise, so the same floats as one call a curve.
    v, r, zc, x0 = (np.array([c[k] for c in curves])[:, None] for k in range(4))
    predicted = cylinder_time(prep.x_m[None, :], x0, zc, r, v, prep.antenna_height_m, prep.tx_rx_offset_m)
    return [pick_along(prep, cand, times, curve[2], search_periods)
            for cand, curve, times in zip(cands, curves, predicted, strict=True)]


def _two_rounds(
    prep: PreparedBScan, cands: Sequence[ApexCandidate], starts: Sequence[tuple[float, float, float, float]], *,
    merge: bool,
) -> dict[int, Reflector]:
    """Picks along the first curves, free-velocity fits, merging (if asked), picks along the fits, refits."""
    curves = [(v, r, zc, float(prep.x_m[c.column])) for c, (v, r, zc, _) in zip(cands, starts, strict=True)]
    picks = _pick_all(prep, cands, curves, 0.5)
    fits = fit_cylinders(prep, picks, [s[0] for s in starts], free_velocity=True)
    # One reflector per target: the strongest candidate's fit stands for the others on the same hyperbola.
    kept: list[tuple[int, CylinderFit]] = []
    for i, f in enumerate(fits):
        if f is not None and not (merge and any(_same_target(f, g) for _, g in kept)):
            kept.append((i, f))
    curves = [(f.v, f.radius_m, f.depth_m, f.x0_m) for _, f in kept]
    again = _pick_all(prep, [cands[i] for i, _ in kept], curves, 0.3)
    refits = fit_cylinders(prep, again, [c[0] for c in curves], free_velocity=True)
    out = {}
    for k, (i, first_fit) in enumerate(kept):
        refit = refits[k]
        if refit is not None and len(again[k].x_m) >= 0.8 * len(picks[i].x_m):
            out[i] = Reflector(cands[i], again[k], refit, starts[i][3])
        else:
            out[i] = Reflector(cands[i], picks[i], first_fit, starts[i][3])
    return out


def fit_reflectors(prep: PreparedBScan, candidates: Sequence[ApexCandidate]) -> tuple[Reflector, ...]:
    """One free-velocity cylinder fit per distinct hyperbola among the candidates (two rounds of picks)."""
    table = line_table(prep, candidates)
    if table is None:
        return ()
    firsts = list(zip(candidates, _first_curves(prep, table, candidates), strict=True))
    cands = [c for c, f in firsts if f is not None]
    starts = [f for _, f in firsts if f is not None]
    if not cands:
        return ()
    return tuple(_two_rounds(prep, cands, starts, merge=True).values())


def fit_each(prep: PreparedBScan, candidates: Sequence[ApexCandidate]) -> list[Reflector | None]:
    """Every candidate fitted as if it were the only one (its own table, no merging), in one batch."""
    firsts: list[tuple[float, float, float, float] | None] = []
    for c in candidates:
        table = line_table(prep, [c])
        firsts.append(None if table is None else _first_curves(prep, table, [c])[0])
    index = [k for k, f in enumerate(firsts) if f is not None]
    out: list[Reflector | None] = [None] * len(candidates)
    if index:
        starts = [f for f in firsts if f is not None]
        for j, r in _two_rounds(prep, [candidates[k] for k in index], starts, merge=False).items():
            out[index[j]] = r
    return out


def refit_each_at_velocity(prep: PreparedBScan, reflectors: Sequence[Reflector],
                           v: float | Sequence[float]) -> list[Reflector | None]:
    """Every hyperbola re-picked along its curve at velocity v (one, or one per reflector) and fitted with it
    fixed (None: too few picks)."""
    out: list[Reflector | None] = [None] * len(reflectors)
    if not reflectors:
        return out
    vs = [float(x) for x in np.broadcast_to(np.asarray(v, dtype=np.float64), (len(reflectors),))]
    first = fit_cylinders(prep, [r.picks for r in reflectors], vs, free_velocity=False)
    done = [(k, r, f) for k, (r, f) in enumerate(zip(reflectors, first, strict=True)) if f is not None]
    curves = [(vs[k], f.radius_m, f.depth_m, f.x0_m) for k, _, f in done]
    again = _pick_all(prep, [r.candidate for _, r, _ in done], curves, 0.3)
    if all(_same_picks(a, r.picks) for a, (_, r, _) in zip(again, done, strict=True)):
        # The same picks at the same velocities make the same batch (same members, same padded length), and
        # a fit is a function of its batch: the first fits stand.
        refits: list[CylinderFit | None] = [f for _, _, f in done]
    else:
        refits = fit_cylinders(prep, again, [vs[k] for k, _, _ in done], free_velocity=False)
    kept = []
    for j, (_, r, f) in enumerate(done):
        refit = refits[j]
        if refit is not None and len(again[j].x_m) >= 0.8 * len(r.picks.x_m):
            kept.append((again[j], refit))
        else:
            kept.append((r.picks, f))
    coherences = curve_coherences(prep, [p for p, _ in kept], [f for _, f in kept])
    for (k, r, _), (picks, fit), coherence in zip(done, kept, coherences, strict=True):
        out[k] = replace(r, picks=picks, fit=fit, coherence=coherence)
    return out


def _same_picks(a: Picks, b: Picks) -> bool:
    """Whether two sets of picks have the same traces and times."""
    return np.array_equal(a.x_m, b.x_m) and np.array_equal(a.t_ns, b.t_ns)


def refit_at_velocity(prep: PreparedBScan, reflectors: Sequence[Reflector],
                      v: float | Sequence[float]) -> tuple[Reflector, ...]:
    """Every hyperbola re-picked along its curve at the line's velocity and fitted with it fixed; one per target."""
    fitted = [r for r in refit_each_at_velocity(prep, reflectors, v) if r is not None]
    # The strongest stands for any others that landed on the same target.
    fitted.sort(key=lambda r: -r.candidate.amplitude)
    out: list[Reflector] = []
    for r in fitted:
        assert r.fit is not None
        if not any(o.fit is not None and _same_target(r.fit, o.fit) for o in out):
            out.append(r)
    return tuple(out)


def curve_coherence(prep: PreparedBScan, picks: Picks, fit: CylinderFit) -> float:
    """Semblance of the traces along the fitted curve, over the picked columns, in a ±quarter-period window."""
    return curve_coherences(prep, [picks], [fit])[0]


def curve_coherences(prep: PreparedBScan, picks: Sequence[Picks], fits: Sequence[CylinderFit]) -> list[float]:
    """`curve_coherence` of each (picks, fit): every fitted curve timed in one call (a row each, padded)."""
    cols = [np.round((p.x_m - prep.x_m[0]) / prep.dx_m).astype(np.intp) for p in picks]
    if not cols:
        return []
    width = max(1, max(len(c) for c in cols))
    at = np.zeros((len(cols), width), dtype=np.intp)  # the padding times column 0, unused
    for row, c in zip(at, cols, strict=True):
        row[: len(c)] = c
    x0, depth, radius, v = (np.array([[getattr(f, k)] for f in fits]) for k in ("x0_m", "depth_m", "radius_m", "v"))
    times = cylinder_time(prep.x_m[at], x0, depth, radius, v, prep.antenna_height_m, prep.tx_rx_offset_m)
    return [_coherence_along(prep, c, t[: len(c)]) if len(c) >= 2 else 0.0 for c, t in zip(cols, times, strict=True)]


def _coherence_along(prep: PreparedBScan, cols: NDArray[np.intp], times: FloatArray) -> float:
    """Semblance of the traces `cols` along the two-way `times`, in a ±quarter-period window."""
    half = max(1, round(0.25 * prep.period_ns / prep.dt_ns))
    s = np.rint((times + prep.t0_ns) / prep.dt_ns).astype(np.intp)[:, None] + np.arange(-half, half + 1)
    ns = prep.data.shape[1]
    vals = np.where((s >= 0) & (s < ns), prep.data[cols[:, None], np.clip(s, 0, ns - 1)], 0.0)
    energy = float(np.sum(vals * vals))
    return float(np.sum(vals.sum(axis=0) ** 2) / (len(cols) * energy)) if energy > 0 else 0.0
