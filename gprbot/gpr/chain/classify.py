"""Stage 5: fitted reflectors → classified detections: pipe or rebar, echoes dropped, a confidence each.

Rules (what a GPR analyst reads off a radargram):
- a **hyperbola** has picks on both flanks (or a long one at the line's end), a small misfit and a
  velocity of its own consistent with the line's;
- an **echo** of another target is dropped: a reflector under a stronger one at the same x, arriving
  within a pipe's inner-echo delay (a PVC pipe's bottom, ringing) or at twice its time (a surface multiple);
- **rebar**: three or more thin reflectors at one cover, evenly spaced (a bar may be missing) —
  a mesh's row; everything else that passes is a **pipe**;
- the reflection's sign against the direct wave says whether the target is slower (metal, water,
  wet) or faster (air-filled, a void) than the host.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from gprbot.gpr.chain.fit import R_MAX_M, CylinderFit
from gprbot.gpr.chain.prepare import PreparedBScan
from gprbot.gpr.chain.reflectors import Reflector

MIN_FLANK_PICKS = 3
MAX_RMS_PERIODS = 0.15
MIN_COHERENCE = 0.25
VELOCITY_TOLERANCE = 0.25  # relative, on top of the fit's own 3 sigma
ROW_MIN_BARS = 3
ROW_DEPTH_TOLERANCE_M = 0.015
ROW_SPACING_TOLERANCE = 0.2  # of the row's base spacing
BAR_MAX_RADIUS_M = 0.02
ECHO_X_TOLERANCE_M = 0.03
MULTIPLE_X_TOLERANCE_M = 0.012
RADIUS_SUPPORT = 0.3  # a radius whose 1-sigma error exceeds this fraction of it is not supported


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


def is_hyperbola(prep: PreparedBScan, r: Reflector, v: float | None) -> bool:
    """Whether a reflector's picks make a diffraction hyperbola consistent with the line's velocity."""
    p, f = r.picks, r.fit or r.free_fit
    edge = min(r.candidate.column, prep.data.shape[0] - 1 - r.candidate.column) <= 2
    flanks = min(p.left, p.right) >= MIN_FLANK_PICKS or (edge and max(p.left, p.right) >= 2 * MIN_FLANK_PICKS)
    if not flanks or f.rms_ns > MAX_RMS_PERIODS * prep.period_ns or r.coherence < MIN_COHERENCE:
        return False
    if f.radius_m >= 0.95 * R_MAX_M:
        return False  # a curve flatter than any pipe: a layer's bump, a multiple, a shadow
    if v is None:
        return True
    free = r.free_fit
    return abs(free.v - v) <= 3.0 * free.sigma_v + VELOCITY_TOLERANCE * v


def _is_echo(a: CylinderFit, b: CylinderFit) -> bool:
    """Whether fit `b` is an echo of the stronger `a`: right below it, within an echo delay."""
    dx = abs(a.x0_m - b.x0_m)
    if b.top_m <= a.top_m or dx > ECHO_X_TOLERANCE_M + a.radius_m:
        return False
    inner = b.top_m - a.top_m <= max(6.0 * a.radius_m, 0.04)  # the bottom of a pipe, ringing
    # Twice the time: a surface multiple, exactly under its primary.
    multiple = dx <= MULTIPLE_X_TOLERANCE_M and abs(b.top_m - 2.0 * a.top_m) <= 0.15 * a.top_m + 0.005
    return inner or multiple


def _rebar_rows(fits: Sequence[CylinderFit]) -> set[int]:
    """Indices of fits that form rebar rows: ≥ 3 thin bars at one cover, evenly spaced."""
    thin = [i for i, f in enumerate(fits) if f.radius_m <= BAR_MAX_RADIUS_M]
    bars: set[int] = set()
    for i in thin:
        row = sorted((j for j in thin if abs(fits[j].top_m - fits[i].top_m) <= ROW_DEPTH_TOLERANCE_M),
                     key=lambda j: fits[j].x0_m)
        if len(row) < ROW_MIN_BARS:
            continue
        gaps = np.diff([fits[j].x0_m for j in row])
        base = float(np.min(gaps[gaps > 0.03])) if np.any(gaps > 0.03) else 0.0
        if base <= 0.0:
            continue
        multiples = gaps / base
        if np.all(np.abs(multiples - np.round(multiples)) <= ROW_SPACING_TOLERANCE) and np.max(multiples) <= 3.5:
            bars.update(row)
    return bars


def _confidence(prep: PreparedBScan, r: Reflector, fit: CylinderFit) -> float:
    """In [0, 1]: apex signal-to-noise, flank length and fit quality, multiplied."""
    snr = 1.0 - math.exp(-r.candidate.snr / 15.0)
    flanks = min(1.0, min(r.picks.left, r.picks.right) / 8.0)
    misfit = math.exp(-fit.rms_ns / (0.05 * prep.period_ns))
    return float(snr * (0.5 + 0.5 * flanks) * (0.5 + 0.5 * misfit) * min(1.0, r.coherence / 0.5))


def classify(prep: PreparedBScan, reflectors: Sequence[Reflector], v: float) -> tuple[ClassifiedDetection, ...]:
    """Accepted hyperbolas (with their fits at the line's velocity), echoes dropped, rebar rows marked."""
    kept = [(r, r.fit) for r in reflectors if r.fit is not None and is_hyperbola(prep, r, v)]
    kept.sort(key=lambda rf: -rf[0].candidate.amplitude)
    primary: list[tuple[Reflector, CylinderFit]] = []
    for r, f in kept:
        if not any(_is_echo(g, f) for _, g in primary):
            primary.append((r, f))
    primary.sort(key=lambda rf: rf[1].x0_m)
    bars = _rebar_rows([f for _, f in primary])
    out = []
    for k, (r, f) in enumerate(primary):
        supported = f.sigma_radius_m <= max(RADIUS_SUPPORT * f.radius_m, 0.003)
        contrast: Literal["slower", "faster"] = "faster" if r.candidate.polarity == prep.direct_polarity else "slower"
        out.append(ClassifiedDetection(f.x0_m, f.depth_m, f.radius_m, f.sigma_radius_m, supported,
                                       "rebar" if k in bars else "pipe", contrast, _confidence(prep, r, f), f, r))
    return tuple(out)
