"""Found pipes against a simulated scene's truth: which truth pipes were found, and their errors.

The matching rule, two-way, so that the counts mean what they say:

* found → truth, "it lies along this pipe": the found axis's mean horizontal distance to the truth
  axis is at most MATCH_GATE_M. Loose on purpose — it only keeps an axis that runs across or away
  from a pipe from being matched to it; how close a match is, the error columns and `within_bounds` say.
* truth → found, "it is this pipe, not a piece of it": the found axis follows the truth over at least
  MIN_COVERAGE of the truth's length inside the surveyed region (a truth point is followed where the
  found axis passes within COVER_DISTANCE_M of it, horizontally).

Why half: the geometric fit runs an axis through the lines whose slices it tracked and extends it half a
line spacing past the outer ones, so a pipe followed through k of the n lines that cross it covers about
k/n of its surveyed length — a complete find about all of it. Counting a pipe as found asks that it was
followed through a majority of its lines; with less, a stub between two lines would be reported as the
pipe (which the one-way rule, before this one, did). Why 5 cm: the scenes' pipes are 1–10 cm in radius,
so within 5 cm the found axis runs inside or at the wall of a typical pipe. A found pipe that lies along
a truth pipe but covers too little of it is an extra, and the table says which pipe it lies on.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.geometry import densify
from gprbot.reconstruct.completion import PipeModel
from gprbot.sim.scene import Pipe, Scene

MATCH_GATE_M = 0.15  # found → truth: mean horizontal distance of the found axis to the truth axis
COVER_DISTANCE_M = 0.05  # truth → found: a truth point is followed where the found axis passes this close
MIN_COVERAGE = 0.5  # truth → found: the share of the truth's surveyed length that must be followed
SAMPLE_STEP_M = 0.01
Region = tuple[float, float, float, float]


@dataclass(frozen=True)
class PipeMatch:
    """One truth pipe and the found pipe matched to it (None when missed)."""

    truth: str
    fill: str
    found: int | None
    horizontal_err_m: float
    depth_err_m: float
    true_diameter_m: float
    found_diameter_m: float
    # share of the truth axis inside the survey that the found axis follows; for a missed pipe, that of
    # the best found pipe lying along it (`partial`), 0 when none does
    coverage: float
    partial: int | None = None

    @property
    def diameter_err_rel(self) -> float:
        """Relative diameter error (found − true) / true."""
        return (self.found_diameter_m - self.true_diameter_m) / self.true_diameter_m


@dataclass(frozen=True)
class _Pair:
    horizontal: float
    depth: float
    coverage: float

    @property
    def lies_along(self) -> bool:
        return self.horizontal <= MATCH_GATE_M

    @property
    def matches(self) -> bool:
        return self.lies_along and self.coverage >= MIN_COVERAGE


def sample_polyline(points: NDArray[np.float64], step: float = SAMPLE_STEP_M) -> NDArray[np.float64]:
    """Points every `step` metres along a 3D polyline (end points included)."""
    return densify(points, step)


def nearest_on_polyline(
    query: NDArray[np.float64], polyline: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Horizontal distance (n,) from each query point to a polyline, and the nearest polyline point (n, 3)."""
    best_d = np.full(len(query), np.inf)
    best_p = np.zeros((len(query), 3))
    for a, b in itertools.pairwise(polyline):
        ab = b[:2] - a[:2]
        s = np.clip(((query[:, :2] - a[:2]) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
        p = a + s[:, None] * (b - a)
        d = np.linalg.norm(query[:, :2] - p[:, :2], axis=1)
        closer = d < best_d
        best_d[closer] = d[closer]
        best_p[closer] = p[closer]
    return best_d, best_p


def _inside(points: NDArray[np.float64], region: Region) -> NDArray[np.bool_]:
    xmin, xmax, ymin, ymax = region
    x, y = points[:, 0], points[:, 1]
    return np.asarray((x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax))


def _pair(truth: Pipe, found: PipeModel, region: Region) -> _Pair:
    f = sample_polyline(found.axis)
    d, p = nearest_on_polyline(f, truth.points)
    t = sample_polyline(truth.points)
    t = t[_inside(t, region)]
    coverage = float(np.mean(nearest_on_polyline(t, found.axis)[0] <= COVER_DISTANCE_M)) if len(t) else 0.0
    return _Pair(float(np.mean(d)), float(np.mean(np.abs(f[:, 2] - p[:, 2]))), coverage)


def lies_on_a_pipe(found: PipeModel, scene: Scene, region: Region) -> bool:
    """Whether a found pipe lies along one of the scene's pipes at its depth (mean horizontal distance within
    MATCH_GATE_M, mean depth within COVER_DISTANCE_M): a piece of a real pipe, matched or not, and no false one."""
    return any(pair.lies_along and pair.depth <= COVER_DISTANCE_M
               for pair in (_pair(t, found, region) for t in scene.pipes))


def compare_to_truth(
    found: Sequence[PipeModel], scene: Scene, region: Region
) -> tuple[list[PipeMatch], list[int]]:
    """Match found pipes to the scene's pipes that cross the surveyed region; return matches and extras."""
    truths = [p for p in scene.pipes if _inside(sample_polyline(p.points), region).any()]
    pairs = {(i, j): _pair(t, f, region) for i, t in enumerate(truths) for j, f in enumerate(found)}
    # Greedy on horizontal error over the pairs that pass both gates; each found pipe serves one truth pipe.
    assigned: dict[int, int] = {}
    for i, j in sorted((k for k in pairs if pairs[k].matches), key=lambda k: pairs[k].horizontal):
        if i not in assigned and j not in assigned.values():
            assigned[i] = j
    matches: list[PipeMatch] = []
    for i, t in enumerate(truths):
        match = assigned.get(i)
        if match is None:
            along = [j for j in range(len(found)) if pairs[(i, j)].lies_along]
            best = max(along, key=lambda j: pairs[(i, j)].coverage, default=None)
            coverage = pairs[(i, best)].coverage if best is not None else 0.0
            matches.append(PipeMatch(t.name, t.fill, None, np.nan, np.nan, 2 * t.radius_m, np.nan, coverage, best))
            continue
        pair = pairs[(i, match)]
        matches.append(PipeMatch(t.name, t.fill, match, pair.horizontal, pair.depth, 2 * t.radius_m,
                                 found[match].diameter_m, pair.coverage))
    extras = [j for j in range(len(found)) if j not in assigned.values()]
    return matches, extras


def format_truth_table(matches: Sequence[PipeMatch], extras: Sequence[int], found: Sequence[PipeModel]) -> str:
    """A plain-text table of found vs true pipes, as `gprbot demo` prints it."""
    width = max([20, *(len(m.truth) + 2 for m in matches)])
    head = f"{'pipe':<{width}}{'fill':<11}{'found':>6}{'horiz cm':>10}{'depth cm':>10}{'diam true':>11}"
    head += f"{'diam found':>12}{'diam err':>10}{'coverage':>10}"
    rule = (f"found = the found axis lies along the pipe (mean {100 * MATCH_GATE_M:.0f} cm) and follows it within "
            f"{100 * COVER_DISTANCE_M:.0f} cm over ≥ {100 * MIN_COVERAGE:.0f} % of its surveyed length")
    rows = [rule, head, "-" * len(head)]
    serves = {m.found: m.truth for m in matches if m.found is not None}
    for m in matches:
        if m.found is None:
            why = ""
            if m.partial is not None:
                why = f"  found pipe {m.partial} lies along it, follows {100 * m.coverage:.0f} %"
            if m.partial in serves:
                why += f" but is {serves[m.partial]}'s"
            rows.append(f"{m.truth:<{width}}{m.fill:<11}{'MISSED':>6}{why}")
            continue
        rows.append(
            f"{m.truth:<{width}}{m.fill:<11}{m.found:>6}{100 * m.horizontal_err_m:>10.1f}{100 * m.depth_err_m:>10.1f}"
            f"{100 * m.true_diameter_m:>9.1f}cm{100 * m.found_diameter_m:>10.1f}cm{100 * m.diameter_err_rel:>9.0f}%"
            f"{100 * m.coverage:>9.0f}%"
        )
    on = {m.partial: m.truth for m in matches if m.partial is not None}
    for j in extras:
        f = found[j]
        where = f", lies along {on[j]} but follows too little of it" if j in on else ""
        rows.append(
            f"{'(extra)':<{width}}{'':<11}{j:>6}  axis from ({f.axis[0][0]:.2f}, {f.axis[0][1]:.2f}) "
            f"to ({f.axis[-1][0]:.2f}, {f.axis[-1][1]:.2f}) m, depth {f.axis[:, 2].mean():.2f} m, "
            f"diameter {100 * f.diameter_m:.1f} cm{where}"
        )
    return "\n".join(rows)


def within_bounds(
    matches: Sequence[PipeMatch], position_m: float = 0.03, depth_m: float = 0.03, diameter_rel: float = 0.30
) -> bool:
    """True when every truth pipe was found (both gates) within the foundation issue's error bounds."""
    return all(
        m.found is not None
        and m.coverage >= MIN_COVERAGE
        and m.horizontal_err_m <= position_m
        and m.depth_err_m <= depth_m
        and abs(m.diameter_err_rel) <= diameter_rel
        for m in matches
    )
