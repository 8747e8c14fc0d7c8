"""Stage 5: fitted reflectors → classified detections: pipe or rebar, echoes dropped, a confidence each.

Rules (what a GPR analyst reads off a radargram):
- a **hyperbola** has picks on both flanks (or a long one at the line's end), a small misfit, a
  velocity of its own consistent with the line's, and an apex earlier than both flanks;
- the lower arms of two neighbours' crossing flanks (a V whose picks lie on their curves) are dropped;
- an **echo** of another target is dropped: a reflector under a stronger one at the same x, arriving
  within a pipe's inner-echo delay (a PVC pipe's bottom, ringing) or at twice its time (a surface multiple);
- **rebar**: four or more reflectors (three if thin; two if thin, shallow and a mesh's spacing apart) at
  one cover on one evenly spaced lattice (bars may be missing, others at that cover may be pipes) — a
  mesh's row; everything else that passes is a **pipe**;
- the reflection's sign against the direct wave says whether the target is slower (metal, water,
  wet) or faster (air-filled, a void) than the host;
- a **radius** is reported as fitted only where the fit measures it (`reported_radius`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from gprbot.gpr.chain.fit import R_MAX_M, CylinderFit
from gprbot.gpr.chain.geometry import cylinder_time
from gprbot.gpr.chain.picks import Picks
from gprbot.gpr.chain.prepare import PreparedBScan
from gprbot.gpr.chain.reflectors import Reflector

MIN_FLANK_PICKS = 3
MIN_FLANK_WAVELENGTHS = 0.4
FLANK_BALANCE = 0.25  # the shorter flank at least this fraction of the longer (else: one-sided)
MAX_RMS_PERIODS = 0.15
MAX_RMS_COHERENT_PERIODS = 0.25
COHERENT = 0.5
MIN_COHERENCE = 0.25
VELOCITY_FACTOR = 2.0  # a hyperbola's own velocity within this factor of the line's (plus 3 sigma)
ROW_MIN_BARS = 3
ROW_DEPTH_TOLERANCE_M = 0.015
ROW_DEPTH_RELATIVE = 0.35
ROW_ANY_RADIUS_BARS = 4
ROW_SITE_TOLERANCE = 0.2  # spacings: bars are tied by hand, a few centimetres off their nominal places
ROW_MIN_FILL = 0.6  # of the sites between a row's end bars hold a reflector (a bar may be missing)
MIN_BAR_SPACING_M = 0.04
BAR_MAX_RADIUS_M = 0.02
# A short line over a mesh may show two bars only: two thin reflectors at one shallow cover, a mesh's
# spacing apart, are a row too (a slab's utilities lie deeper than its reinforcement's cover).
PAIR_MAX_COVER_M = 0.08
PAIR_MAX_SPACING_M = 0.35
ECHO_X_TOLERANCE_M = 0.03
MULTIPLE_X_TOLERANCE_M = 0.012
STRAIGHT_RATIO = 2.0  # a hyperbola fits its picks at least this much better than a straight line
ON_FLANK_PERIODS = 0.3
ON_FLANK_FRACTION = 0.6
# A radius whose 1-sigma error exceeds this fraction of it is not supported (FDTD dev: two fits at 22-29 % ran
# 1.1x and 3.6x the true radius).
RADIUS_SUPPORT = 0.2


RadiusSource = Literal["fit", "survey", "migrationnet", "none"]


@dataclass(frozen=True)
class ClassifiedDetection:
    """A target crossing the line: centre x and depth (m), radius with its error, kind, contrast, confidence."""

    x_m: float
    depth_m: float
    radius_m: float
    radius_sigma_m: float
    radius_supported: bool
    kind: Literal["pipe", "rebar"]
    contrast: Literal["slower", "faster"]  # than the host: metal/water/wet vs air/void
    confidence: float
    fit: CylinderFit
    reflector: Reflector
    found_by: Literal["hyperbola", "migrated spot"] = "hyperbola"  # which stage found it (see spots.py)
    sin_cross: float = 1.0  # sine of the angle the pipe crosses the line at (1: at right angles; a survey's hint)
    # where the reported radius comes from: the curve's fit (it measures it), the survey's lines (`run.holding`),
    # MigrationNet's pipe mask (`sizing`), or none (the middle of what the curve allows)
    radius_source: RadiusSource = "none"


def is_hyperbola(prep: PreparedBScan, r: Reflector, v: float | None) -> bool:
    """Whether a reflector's picks make a diffraction hyperbola consistent with the line's velocity."""
    p, f = r.picks, r.fit or r.free_fit
    edge = min(r.candidate.column, prep.data.shape[0] - 1 - r.candidate.column) <= 2
    # Each flank must run a fair part of a wavelength (in the ground) along the line: on a coarse
    # low-frequency line three picks are a few centimetres of clutter, not a flank.
    wavelength = prep.wavelength_m(v if v else 0.1)
    least = max(MIN_FLANK_PICKS, math.ceil(MIN_FLANK_WAVELENGTHS * wavelength / prep.dx_m))
    two_sided = min(p.left, p.right) >= max(least, FLANK_BALANCE * max(p.left, p.right))
    flanks = two_sided or (edge and max(p.left, p.right) >= 2 * least)
    if not flanks or r.coherence < MIN_COHERENCE:
        return False
    # A loose fit passes only when the traces are coherent along it (a weak shallow bar under the
    # direct wave's tail, or crossed by a neighbour's flank, picks poorly but stacks well).
    limit = MAX_RMS_PERIODS if r.coherence < COHERENT else MAX_RMS_COHERENT_PERIODS
    if f.rms_ns > limit * prep.period_ns:
        return False
    if f.radius_m >= 0.95 * R_MAX_M:
        return False  # a curve flatter than any pipe: a layer's bump, a multiple, a shadow
    if not prep.x_m[0] - prep.dx_m <= f.x0_m <= prep.x_m[-1] + prep.dx_m:
        return False  # its top lies off the line: a slab edge's or a dipping event's straight arm
    if not two_sided and not _curved(p.x_m, p.t_ns, f.rms_ns):
        return False  # one flank only, and straight: a dipping event or a slab edge, not a diffraction
    if two_sided and not descends_on_both_flanks(prep, p, f):
        return False  # not earliest on both sides: a layer's kink or a flat stretch, not an apex
    if v is None:
        return True
    # On one hyperbola radius and velocity trade off, so its own velocity only rules out the absurd.
    free = r.free_fit
    return abs(math.log(free.v / v)) <= math.log(VELOCITY_FACTOR) + 3.0 * free.sigma_v / v


def descends_on_both_flanks(prep: PreparedBScan, p: Picks, fit: CylinderFit) -> bool:
    """Whether both flanks arrive later than the apex by at least half what the fitted curve predicts,
    at the farthest offset both reach.

    A diffraction's apex is its earliest point and its flanks descend alike; the top of a dipping
    layer's kink, or a flat stretch between two bumps, has one side level or rising while a curve
    fitted through both still bends (MALÅ geology line: five such, one side at -0.38 to +0.01 periods
    against +0.02 to +0.16 predicted).
    """
    left, right = p.x_m < fit.x0_m, p.x_m > fit.x0_m
    n = min(int(left.sum()), int(right.sum()))
    if n == 0:
        return False
    apex = int(np.argmin(np.abs(p.x_m - fit.x0_m)))
    ends = np.array([p.x_m[left][-n], p.x_m[right][n - 1], p.x_m[apex]])
    curve = cylinder_time(ends, fit.x0_m, fit.depth_m, fit.radius_m, fit.v, prep.antenna_height_m,
                          prep.tx_rx_offset_m)
    observed = min(float(p.t_ns[left][-n]), float(p.t_ns[right][n - 1])) - float(p.t_ns[apex])
    return observed >= 0.5 * (min(float(curve[0]), float(curve[1])) - float(curve[2]))


def _curved(x: np.ndarray, t: np.ndarray, rms_ns: float) -> bool:
    """Whether picks bend: a straight line through them leaves clearly more misfit than the hyperbola."""
    if len(x) < 4:
        return False
    design = np.stack([np.ones_like(x), x], axis=1)
    coef, *_ = np.linalg.lstsq(design, t, rcond=None)
    line_rms = float(np.sqrt(np.mean((design @ coef - t) ** 2)))
    return line_rms > STRAIGHT_RATIO * rms_ns + 1e-3


def _is_echo(a: CylinderFit, b: CylinderFit) -> bool:
    """Whether fit `b` is an echo of the stronger `a`: right below it, within an echo delay."""
    dx = abs(a.x0_m - b.x0_m)
    if b.top_m <= a.top_m or dx > ECHO_X_TOLERANCE_M + a.radius_m:
        return False
    inner = b.top_m - a.top_m <= max(6.0 * a.radius_m, 0.04)  # the bottom of a pipe, ringing
    # Twice the time: a surface multiple, exactly under its primary.
    multiple = dx <= MULTIPLE_X_TOLERANCE_M and abs(b.top_m - 2.0 * a.top_m) <= 0.15 * a.top_m + 0.005
    return inner or multiple


def _on_other_flanks(prep: PreparedBScan, r: Reflector, stronger: Sequence[CylinderFit]) -> bool:
    """Whether a reflector's picks run along stronger hyperbolas' flanks: the lower arms of two crossing flanks.

    Where two neighbours' flanks cross, the later arms form a V that looks like an apex; its picks lie
    on the curves already found.
    """
    if not stronger or len(r.picks.x_m) == 0:
        return False
    h, off = prep.antenna_height_m, prep.tx_rx_offset_m
    curves = np.stack([cylinder_time(r.picks.x_m, g.x0_m, g.depth_m, g.radius_m, g.v, h, off) for g in stronger])
    near = np.min(np.abs(curves - r.picks.t_ns[None, :]), axis=0) <= ON_FLANK_PERIODS * prep.period_ns
    return float(np.mean(near)) >= ON_FLANK_FRACTION


def _lattice(xs: Sequence[float], fewest: int = ROW_MIN_BARS) -> list[int]:
    """Indices of the positions (sorted) that sit on one evenly spaced lattice: the mesh's bar positions.

    Every pair of near neighbours (up to three places apart in x), one to three spacings apart, proposes
    a lattice; the one holding the most positions wins (closest fit on a tie). A position belongs when it
    lies within ROW_SITE_TOLERANCE spacings of a site, one per site; the lattice must be filled to
    ROW_MIN_FILL between its ends. So an interloper at the same cover (a pipe, a neighbour's crossing
    flanks halfway between two bars) and missing bars (shadowed, not picked) leave the row a row.
    """
    best: list[int] = []
    best_misfit = math.inf
    for i, xi in enumerate(xs):
        for xj in xs[i + 1: i + 4]:
            for k in (1, 2, 3):
                spacing = (xj - xi) / k
                if spacing < MIN_BAR_SPACING_M:
                    continue
                on_site: dict[int, tuple[float, int]] = {}
                for m, x in enumerate(xs):
                    site = round((x - xi) / spacing)
                    off = abs(x - xi - site * spacing) / spacing
                    if off <= ROW_SITE_TOLERANCE and (site not in on_site or off < on_site[site][0]):
                        on_site[site] = (off, m)
                sites = sorted(on_site)
                if len(sites) < max(fewest, len(best)):
                    continue
                filled = len(sites) / (sites[-1] - sites[0] + 1)
                if filled < ROW_MIN_FILL:
                    continue
                misfit = sum(off for off, _ in on_site.values()) / len(sites)
                if len(sites) > len(best) or misfit < best_misfit:
                    best, best_misfit = [on_site[q][1] for q in sites], misfit
    return best


def _rebar_rows(fits: Sequence[CylinderFit]) -> set[int]:
    """Indices of fits that form rebar rows: evenly spaced reflectors at one cover (a bar may be missing).

    Four or more make a row whatever their fitted radius (pipes are not laid in regular rows, and on
    one line radius and velocity trade off); three only when they are thin; two only when thin, within
    PAIR_MAX_COVER_M of the surface and at most PAIR_MAX_SPACING_M apart.
    """
    bars: set[int] = set()
    order = sorted(range(len(fits)), key=lambda i: fits[i].top_m)
    seen: set[tuple[int, ...]] = set()
    for i in order:
        cover = fits[i].top_m
        tol = max(ROW_DEPTH_TOLERANCE_M, ROW_DEPTH_RELATIVE * cover)
        row = sorted((j for j in range(len(fits)) if abs(fits[j].top_m - cover) <= tol), key=lambda j: fits[j].x0_m)
        if tuple(row) in seen:  # neighbours at one cover see the same row
            continue
        seen.add(tuple(row))
        fewest = 2 if cover <= PAIR_MAX_COVER_M else ROW_MIN_BARS
        run = [row[m] for m in _lattice([fits[j].x0_m for j in row], fewest)]
        thin = all(fits[j].radius_m - fits[j].sigma_radius_m <= BAR_MAX_RADIUS_M for j in run)  # or not measurable
        if len(run) == 2 and not abs(fits[run[1]].x0_m - fits[run[0]].x0_m) <= PAIR_MAX_SPACING_M:
            continue
        if run and (len(run) >= ROW_ANY_RADIUS_BARS or thin):
            bars.update(run)
    return bars


def _confidence(prep: PreparedBScan, r: Reflector, fit: CylinderFit) -> float:
    """In [0, 1]: apex signal-to-noise, flank length and fit quality, multiplied."""
    snr = 1.0 - math.exp(-r.candidate.snr / 15.0)
    flanks = min(1.0, min(r.picks.left, r.picks.right) / 8.0)
    misfit = math.exp(-fit.rms_ns / (0.05 * prep.period_ns))
    return float(snr * (0.5 + 0.5 * flanks) * (0.5 + 0.5 * misfit) * min(1.0, r.coherence / 0.5))


def reported_radius(fit: CylinderFit) -> tuple[float, float, bool]:
    """(radius, 1-sigma, supported): the fit's where its curve measures it, else the middle of [0, fitted], ± at
    least half of it.

    The curvature that tells a pipe from a bar is a few tens of picoseconds on the flanks, the size of
    the difference between any ray model and the data; where the fit's error bar is wider than the
    radius, the truth lies anywhere from a thin bar up to about the fitted value (FDTD dev half: such
    fits ran 0.3-2.5x the true radius, median 1.35x), and the centre is put in the middle of that range.
    """
    if fit.sigma_radius_m <= max(RADIUS_SUPPORT * fit.radius_m, 0.003):
        return fit.radius_m, fit.sigma_radius_m, True
    half = 0.5 * fit.radius_m
    # Never surer than the fit itself: a curve fitted at radius 0 with a wide error is no "0 ± 0".
    return half, max(half, fit.sigma_radius_m), False


def classify(prep: PreparedBScan, reflectors: Sequence[Reflector], v: float) -> tuple[ClassifiedDetection, ...]:
    """Accepted hyperbolas (with their fits at the line's velocity), echoes dropped, rebar rows marked."""
    kept = [(r, r.fit) for r in reflectors if r.fit is not None and is_hyperbola(prep, r, v)]
    kept.sort(key=lambda rf: -rf[0].candidate.amplitude)
    primary: list[tuple[Reflector, CylinderFit]] = []
    for r, f in kept:
        if not any(_is_echo(g, f) for _, g in primary) and not _on_other_flanks(prep, r, [g for _, g in primary]):
            primary.append((r, f))
    primary.sort(key=lambda rf: rf[1].x0_m)
    bars = _rebar_rows([f for _, f in primary])
    out = []
    for k, (r, f) in enumerate(primary):
        radius, sigma, supported = reported_radius(f)
        contrast: Literal["slower", "faster"] = "faster" if r.candidate.polarity == prep.direct_polarity else "slower"
        out.append(ClassifiedDetection(f.x0_m, f.top_m + radius, radius, sigma, supported,
                                       "rebar" if k in bars else "pipe", contrast, _confidence(prep, r, f), f, r,
                                       radius_source="fit" if supported else "none"))
    return tuple(out)


def relabel_rows(detections: Sequence[ClassifiedDetection]) -> tuple[ClassifiedDetection, ...]:
    """The detections with their pipe/rebar kind decided again on this set (after some were dropped)."""
    bars = _rebar_rows([d.fit for d in detections])
    return tuple(replace(d, kind="rebar" if k in bars else "pipe") for k, d in enumerate(detections))
