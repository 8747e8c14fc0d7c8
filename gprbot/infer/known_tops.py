"""A survey's velocity calibrated on targets whose cover the inspector knows (a cover meter reading, a core).

No hyperbola's curve gives the velocity to a few per cent while the target's radius is unknown
(`validation.hyperbola_signatures`); a known depth does (`gprbot.gpr.chain.calibrate`; one FDTD line:
median error 5-6 % against the chain's 11-15 %). Here each known top, given in the site frame, is
found on the survey line that passes nearest to it, calibrated there, and the lines' calibrations are
combined (their median weighted by 1/sigma²): one velocity for every line, as the survey's estimate would be.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from gprbot.config import GprConfig, Vec3
from gprbot.errors import InterpretationError
from gprbot.gpr.bscan import BScan
from gprbot.gpr.chain.calibrate import KnownTop, calibrate
from gprbot.gpr.chain.candidates import apex_candidates
from gprbot.gpr.chain.prepare import prepare
from gprbot.gpr.chain.reflectors import fit_reflectors
from gprbot.gpr.chain.velocity import weighted_median

log = logging.getLogger(__name__)

MAX_OFF_LINE_M = 0.1  # a known top further than this (in plan) from every recorded trace is on no line


@dataclass(frozen=True)
class SurveyCalibration:
    """The calibrated velocity (None: no known top could be used), its 1-sigma, how, and what was not used."""

    v: float | None
    sigma: float
    method: str
    notes: tuple[str, ...]


def on_nearest_line(lines: Mapping[int, BScan], xy: tuple[float, float]) -> tuple[int, float, float] | None:
    """(line, metres along it from its first trace, plan distance) of the trace nearest to xy; None if no line."""
    best: tuple[int, float, float] | None = None
    for line, b in lines.items():
        d = np.hypot(b.positions[:, 0] - xy[0], b.positions[:, 1] - xy[1])
        k = int(np.argmin(d))
        if best is None or d[k] < best[2]:
            best = (line, float(b.along_track_m()[k]), float(d[k]))
    return best


def calibrate_survey(lines: Mapping[int, BScan], gpr: GprConfig, tops: Sequence[Vec3],
                     prior_v: float | None = None) -> SurveyCalibration:
    """The survey's velocity from the known tops (x, y, depth of the top; site frame, m) on its lines;
    `prior_v` (the survey's estimate from its hyperbolas) tells each top's apex from its neighbours'."""
    notes: list[str] = []
    per_line: dict[int, list[KnownTop]] = {}
    for x, y, depth in tops:
        found = on_nearest_line(lines, (x, y))
        if found is None or found[2] > MAX_OFF_LINE_M:
            off = "no line" if found is None else f"{100 * found[2]:.0f} cm from the nearest line ({found[0]})"
            notes.append(f"the known top at ({x:.2f}, {y:.2f}) m, {100 * depth:.1f} cm deep, lies {off}: not used; "
                         f"give a point on a surveyed line")
            continue
        per_line.setdefault(found[0], []).append(KnownTop(found[1], depth))
    votes = []
    for line, known in sorted(per_line.items()):
        try:
            prep = prepare(lines[line], gpr)
        except InterpretationError as exc:
            notes.append(f"line {line} could not be read for its known tops: {exc}")
            continue
        result = calibrate(prep, fit_reflectors(prep, apex_candidates(prep)), known, prior_v)
        notes += [f"line {line}: {n}" for n in result.notes]
        if result.estimate is not None and result.estimate.sigma > 0:
            where = ", ".join(f"{100 * k.top_m:.1f} cm at {k.x_m:.2f} m along it" for k in known)
            votes.append((result.estimate.v, result.estimate.sigma, f"line {line}: {where}"))
            log.info("known tops on line %d: %s", line, result.estimate.method)
    if not votes:
        return SurveyCalibration(None, math.nan, "", tuple(notes))
    v = weighted_median(np.array([a for a, _, _ in votes]), np.array([1.0 / s**2 for _, s, _ in votes]))
    sigma = math.sqrt(1.0 / sum(1.0 / s**2 for _, s, _ in votes))
    how = f"calibrated on {len(votes)} known top{'s' if len(votes) > 1 else ''} ({'; '.join(m for _, _, m in votes)})"
    return SurveyCalibration(v, sigma, how, tuple(notes))
