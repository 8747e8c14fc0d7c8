"""Where a fitted pipe might continue: its axis pushed on to the survey's edge, and each point's distance past its end.

The geometric fit claims a pipe only from the first to the last line that saw it (plus half a line
spacing). Past that the slices say nothing, but pipes rarely end where a line stopped seeing them: an
interpreter misses a weak or shallow-angle crossing, a line is missing. The learned completion
(gprbot.infer.refine) is asked, point by point, whether the pipe goes on; these are the candidates.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.geometry import closest_points_of_segments, drop_repeated_vertices, polyline_length, sample_rods
from gprbot.reconstruct.completion import PipeModel
from gprbot.reconstruct.register import SliceCloud

MAX_EXTENSION_M = 1.5  # no pipe end is pushed further than this, whatever the survey's size
MAX_UNSEEN_CROSSINGS = 1  # recorded lines in a row that may miss a continued pipe (an interpreter misses a weak one)
SUPPORT_MIN_M = 0.1  # a line supports a continued pipe with a slice point this close in plan (or 3 radii) ...
SUPPORT_DEPTH_M = 0.1  # ... and within this (plus 3 radii) of the axis' depth there
MEET_MARGIN_M = 0.01  # a pushed-on end meets another pipe when the axes pass within the larger radius + this, ...
MEET_SLACK_PER_M = 0.05  # ... plus this per metre pushed on (a direction from few centres is a few % off)
SIDE_BY_SIDE_COS = 0.95  # two ends pushed on the same way this near parallel run side by side: they never meet
Footprint = tuple[float, float, float, float]  # xmin, xmax, ymin, ymax of the surveyed area (m)


@dataclass(frozen=True)
class ExtendedAxis:
    """An axis pushed on at its free ends: the polyline and how much was added at the start and the end (m)."""

    axis: NDArray[np.float64]
    added: tuple[float, float]


def survey_footprint(positions_per_line: Mapping[int, NDArray[np.float64]]) -> Footprint:
    """The area the lines covered: their antenna positions' box, widened by half the median line spacing."""
    lines = [np.asarray(p, dtype=np.float64)[:, :2] for p in positions_per_line.values() if len(p)]
    if not lines:
        raise ValueError("a survey footprint needs at least one line with positions")
    allxy = np.concatenate(lines)
    centres = np.array([line.mean(axis=0) for line in lines])
    # Lines run side by side: across them is the axis along which each line itself hardly moves (not the survey's
    # shorter side: six lines 0.32 m apart over 1.37 m runs span more across than along), and their spacing is
    # the gap between neighbouring centres on it.
    own_extent = np.median([line.max(axis=0) - line.min(axis=0) for line in lines], axis=0)
    across = int(np.argmin(own_extent))
    gaps = np.diff(np.sort(centres[:, across]))
    half = 0.5 * float(np.median(gaps)) if len(gaps) else 0.0
    lo, hi = allxy.min(axis=0), allxy.max(axis=0)
    lo[across] -= half
    hi[across] += half
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def distance_to_edge(point: NDArray[np.float64], direction: NDArray[np.float64], footprint: Footprint) -> float:
    """How far a ray from point (horizontal part of direction) runs before it leaves the footprint (0 if outside)."""
    xmin, xmax, ymin, ymax = footprint
    x, y = float(point[0]), float(point[1])
    if not (xmin <= x <= xmax and ymin <= y <= ymax):
        return 0.0
    run = np.inf
    for k, (lo, hi) in enumerate(((xmin, xmax), (ymin, ymax))):
        d = float(direction[k])
        if abs(d) > 1e-9:
            run = min(run, ((hi if d > 0 else lo) - float(point[k])) / d)
    return float(run) if np.isfinite(run) else 0.0


def extend_to_footprint(axis: NDArray[np.float64], ends_on: tuple[int | None, int | None],
                        footprint: Footprint) -> ExtendedAxis:
    """The axis pushed straight on at each end that joins no other pipe, to the footprint's edge (≤ MAX_EXTENSION_M)."""
    axis = np.asarray(axis, dtype=np.float64)
    if len(axis) < 2:
        return ExtendedAxis(axis, (0.0, 0.0))
    added = []
    ends = []
    for end, inner, joined in ((axis[0], axis[1], ends_on[0]), (axis[-1], axis[-2], ends_on[1])):
        outward = end - inner
        norm = float(np.linalg.norm(outward))
        length = 0.0
        if joined is None and norm > 1e-9:
            outward = outward / norm
            horizontal = float(np.linalg.norm(outward[:2]))
            if horizontal > 1e-6:
                length = min(distance_to_edge(end, outward / horizontal, footprint) / horizontal, MAX_EXTENSION_M)
        added.append(length)
        ends.append(end + (outward * length if length > 0 else 0.0))
    extended = drop_repeated_vertices(np.vstack([ends[0], axis[1:-1], ends[1]]) if len(axis) > 2
                                      else np.vstack([ends[0], ends[1]]))
    return ExtendedAxis(extended, (added[0], added[1]))


def _crossings(start: NDArray[np.float64], step: NDArray[np.float64], length: float,
               slices: Sequence[SliceCloud]) -> list[tuple[float, SliceCloud]]:
    """Where the segment start + s·step (0 < s ≤ length, plan view) crosses a recorded line's track, nearest first."""
    out = []
    for sl in slices:
        if sl.track_xy is None:
            continue
        a, b = sl.track_xy
        # start + s·step = a + u·(b − a): two equations in (s, u)
        system = np.array([[step[0], a[0] - b[0]], [step[1], a[1] - b[1]]])
        if abs(float(np.linalg.det(system))) < 1e-12:
            continue  # running along the line: it crosses nothing
        s, u = np.linalg.solve(system, a - start[:2])
        if 1e-6 < s <= length and 0.0 <= u <= 1.0:
            out.append((float(s), sl))
    return sorted(out, key=lambda c: c[0])


def _supports(sl: SliceCloud, point: NDArray[np.float64], radius: float) -> bool:
    """Whether a line's slice has a point near where a continued pipe would cross it."""
    if len(sl.points) == 0:
        return False
    near_xy = np.hypot(sl.points[:, 0] - point[0], sl.points[:, 1] - point[1]) <= max(SUPPORT_MIN_M, 3.0 * radius)
    near_z = np.abs(sl.points[:, 2] - point[2]) <= SUPPORT_DEPTH_M + 3.0 * radius
    return bool(np.any(near_xy & near_z))


def seen_extension(ext: ExtendedAxis, radius: float, slices: Sequence[SliceCloud]) -> ExtendedAxis:
    """The extension cut where recorded lines stop seeing the pipe: past MAX_UNSEEN_CROSSINGS lines in a row whose
    slices show nothing where it would cross them, it ends half-way back to the line before.

    A line that was recorded and interpreted, and shows nothing there, is evidence the pipe does not go on (a bend's
    leg pushed straight on past the corner crossed eight such lines on a simulated survey); a missing line is none.
    """
    cut = list(ext.added)
    total = polyline_length(ext.axis)
    for k, (tip, inner) in enumerate(((ext.axis[0], ext.axis[1]), (ext.axis[-1], ext.axis[-2]))):
        added = ext.added[k]
        if added <= 0.0:
            continue
        direction = (tip - inner) / max(float(np.linalg.norm(tip - inner)), 1e-12)
        origin = tip - direction * added  # where the fitted part ended
        unseen, previous = 0, 0.0
        for s, sl in _crossings(origin, direction[:2], added, slices):
            if _supports(sl, origin + direction * s, radius):
                unseen = 0
            else:
                unseen += 1
                if unseen > MAX_UNSEEN_CROSSINGS:
                    cut[k] = 0.5 * (previous + s)
                    break
            previous = s
    if cut == list(ext.added):
        return ext
    axis = cut_polyline(ext.axis, ext.added[0] - cut[0], total - (ext.added[1] - cut[1]))
    return ExtendedAxis(axis, (cut[0], cut[1]))


def _added_part(ext: ExtendedAxis, end: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where the fitted part ended and the tip, for one end (0: start, 1: end) of an extended axis."""
    tip, inner = (ext.axis[0], ext.axis[1]) if end == 0 else (ext.axis[-1], ext.axis[-2])
    direction = (tip - inner) / max(float(np.linalg.norm(tip - inner)), 1e-12)
    return tip - direction * ext.added[end], tip


def _fitted_part(ext: ExtendedAxis) -> NDArray[np.float64]:
    """The extended axis less what was added at its ends."""
    return cut_polyline(ext.axis, ext.added[0], polyline_length(ext.axis) - ext.added[1])


def met_extensions(extended: Sequence[ExtendedAxis], radii: Sequence[float]) -> tuple[ExtendedAxis, ...]:
    """The extensions cut where they run into another pipe, shortest push first.

    Two pushed-on ends that meet are the legs of a bend whose corner no line saw: both stop at the meeting point
    (pushed straight on, each ran past the corner). An end that runs into another pipe's fitted part stops on its
    axis (a tee further from the last sighting than the fit's own join reaches).
    """
    ends = [(k, e) for k, ext in enumerate(extended) for e in (0, 1) if ext.added[e] > 0.0]
    parts = {(k, e): _added_part(extended[k], e) for k, e in ends}
    fitted = [_fitted_part(ext) for ext in extended]
    meetings: list[tuple[float, tuple[int, int], float, tuple[int, int] | None, float]] = []
    for i, (k, e) in enumerate(ends):
        o, tip = parts[(k, e)]
        length = extended[k].added[e]
        for q, f in ends[i + 1:]:
            if q == k:
                continue
            o2, tip2 = parts[(q, f)]
            length2 = extended[q].added[f]
            if float((tip - o) @ (tip2 - o2)) > SIDE_BY_SIDE_COS * length * length2:
                continue
            s, t, distance = closest_points_of_segments(o, tip, o2, tip2)
            gate = max(radii[k], radii[q]) + MEET_MARGIN_M + MEET_SLACK_PER_M * (s * length + t * length2)
            if distance <= gate:
                meetings.append((s * length + t * length2, (k, e), s * length, (q, f), t * length2))
        for q, other in enumerate(fitted):
            if q == k:
                continue
            for a, b in itertools.pairwise(other):
                s, _, distance = closest_points_of_segments(o, tip, a, b)
                if distance <= radii[q] + MEET_MARGIN_M + MEET_SLACK_PER_M * s * length:
                    meetings.append((s * length, (k, e), s * length, None, 0.0))
    kept: dict[tuple[int, int], float] = {}
    for _, end, pushed, met_end, met_pushed in sorted(meetings, key=lambda m: m[0]):
        if end in kept or (met_end is not None and met_end in kept):
            continue
        kept[end] = pushed
        if met_end is not None:
            kept[met_end] = met_pushed
    out = []
    for k, ext in enumerate(extended):
        added = (kept.get((k, 0), ext.added[0]), kept.get((k, 1), ext.added[1]))
        if added == ext.added:
            out.append(ext)
            continue
        total = polyline_length(ext.axis)
        axis = cut_polyline(ext.axis, ext.added[0] - added[0], total - (ext.added[1] - added[1]))
        out.append(ExtendedAxis(axis, added))
    return tuple(out)


def arclength_on(points: NDArray[np.float64], polyline: NDArray[np.float64]) -> NDArray[np.float64]:
    """Arc length (m from the polyline's start) of each point's nearest point on the polyline."""
    points = np.atleast_2d(points)
    best_d = np.full(len(points), np.inf)
    best_s = np.zeros(len(points))
    start = 0.0
    for a, b in itertools.pairwise(polyline):
        ab = b - a
        length = float(np.linalg.norm(ab))
        t = np.clip((points - a) @ ab / max(length**2, 1e-12), 0.0, 1.0)
        d = np.linalg.norm(points - (a + np.outer(t, ab)), axis=1)
        closer = d < best_d
        best_d[closer], best_s[closer] = d[closer], start + t[closer] * length
        start += length
    return best_s


def beyond_fit(
    points: NDArray[np.float64], owner: NDArray[np.integer], extended: Sequence[ExtendedAxis]
) -> NDArray[np.float64]:
    """For each point of an extended rod, how far (m, along the axis) it lies past the fitted part (0 inside it)."""
    out = np.zeros(len(points))
    for k, ext in enumerate(extended):
        mine = np.flatnonzero(owner == k)
        if len(mine) == 0:
            continue
        s = arclength_on(points[mine], ext.axis)
        total = polyline_length(ext.axis)
        out[mine] = np.maximum.reduce([ext.added[0] - s, s - (total - ext.added[1]), np.zeros(len(s))])
    return out


def cut_polyline(polyline: NDArray[np.float64], s0: float, s1: float) -> NDArray[np.float64]:
    """The part of a polyline between arc lengths s0 < s1 (clamped to it)."""
    lengths = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    s0, s1 = max(0.0, s0), min(float(cumulative[-1]), s1)

    def at(s: float) -> NDArray[np.float64]:
        k = int(np.clip(np.searchsorted(cumulative, s, side="right") - 1, 0, len(lengths) - 1))
        t = (s - cumulative[k]) / max(float(lengths[k]), 1e-12)
        return np.asarray(polyline[k] + t * (polyline[k + 1] - polyline[k]))

    inner = polyline[(cumulative > s0) & (cumulative < s1)]
    return drop_repeated_vertices(np.vstack([at(s0), inner, at(s1)]))


@dataclass(frozen=True)
class RodCandidates:
    """Points of the fitted rods (the network's view of the fit) and of the extended rods (the candidates)."""

    extended: tuple[ExtendedAxis, ...]
    fit: NDArray[np.float64]
    fit_pipe: NDArray[np.int64]
    query: NDArray[np.float64]
    query_pipe: NDArray[np.int64]
    beyond_m: NDArray[np.float64]


def rod_candidates(pipes: Sequence[PipeModel], footprint: Footprint, n_fit: int, n_query: int,
                   rng: np.random.Generator, slices: Sequence[SliceCloud] = ()) -> RodCandidates | None:
    """Sample the fitted rods and the rods extended to the footprint (cut where the `slices`' recorded lines stop
    seeing them, and where they run into another pipe); None when nothing lies in the footprint."""
    axes, radii = [p.axis for p in pipes], [p.radius_m for p in pipes]
    extended = met_extensions([seen_extension(extend_to_footprint(p.axis, p.ends_on, footprint), p.radius_m, slices)
                               for p in pipes], radii)
    fit, fit_pipe = sample_rods(axes, radii, n_fit, rng)
    query, query_pipe = sample_rods([e.axis for e in extended], radii, n_query, rng, region_xy=footprint)
    if len(fit) < n_fit or len(query) < n_query:
        if len(query) == 0 or len(fit) == 0:
            return None
        query, query_pipe = _exactly(query, query_pipe, n_query, rng)
        fit, fit_pipe = _exactly(fit, fit_pipe, n_fit, rng)
    return RodCandidates(extended, fit, fit_pipe, query, query_pipe, beyond_fit(query, query_pipe, extended))


def _exactly(points: NDArray[np.float64], owner: NDArray[np.int64], n: int,
             rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    pick = rng.choice(len(points), size=n, replace=len(points) < n)
    return points[pick], owner[pick]
