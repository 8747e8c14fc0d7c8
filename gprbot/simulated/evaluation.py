"""Found pipes against a simulated scene's truth: position, depth and diameter errors per pipe."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.geometry import densify
from gprbot.reconstruct.completion import PipeModel
from gprbot.sim.scene import Pipe, Scene

MATCH_GATE_M = 0.15  # a found pipe further than this (mean horizontal distance) matches nothing
SAMPLE_STEP_M = 0.01


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
    coverage: float  # fraction of the truth axis inside the survey that the found axis runs along

    @property
    def diameter_err_rel(self) -> float:
        """Relative diameter error (found − true) / true."""
        return (self.found_diameter_m - self.true_diameter_m) / self.true_diameter_m


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


def _inside(points: NDArray[np.float64], region: tuple[float, float, float, float]) -> NDArray[np.bool_]:
    xmin, xmax, ymin, ymax = region
    x, y = points[:, 0], points[:, 1]
    return np.asarray((x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax))


def _match_cost(truth: Pipe, found: PipeModel, region: tuple[float, float, float, float]) -> tuple[float, ...]:
    f = sample_polyline(found.axis)
    d, p = nearest_on_polyline(f, truth.points)
    horizontal = float(np.mean(d))
    depth = float(np.mean(np.abs(f[:, 2] - p[:, 2])))
    t = sample_polyline(truth.points)
    t = t[_inside(t, region)]
    coverage = float(np.mean(nearest_on_polyline(t, found.axis)[0] < 0.05)) if len(t) else 0.0
    return horizontal, depth, coverage


def compare_to_truth(
    found: Sequence[PipeModel], scene: Scene, region: tuple[float, float, float, float]
) -> tuple[list[PipeMatch], list[int]]:
    """Match found pipes to the scene's pipes that cross the surveyed region; return matches and extras."""
    truths = [p for p in scene.pipes if _inside(sample_polyline(p.points), region).any()]
    costs = {(i, j): _match_cost(t, f, region) for i, t in enumerate(truths) for j, f in enumerate(found)}
    matches: list[PipeMatch] = []
    used: set[int] = set()
    # Greedy on horizontal error; each found pipe serves at most one truth pipe.
    order = sorted(costs, key=lambda k: costs[k][0])
    assigned: dict[int, int] = {}
    for i, j in order:
        if i in assigned or j in used or costs[(i, j)][0] > MATCH_GATE_M:
            continue
        assigned[i] = j
        used.add(j)
    for i, t in enumerate(truths):
        match = assigned.get(i)
        if match is None:
            matches.append(PipeMatch(t.name, t.fill, None, np.nan, np.nan, 2 * t.radius_m, np.nan, 0.0))
            continue
        horizontal, depth, coverage = costs[(i, match)]
        matches.append(
            PipeMatch(t.name, t.fill, match, horizontal, depth, 2 * t.radius_m, found[match].diameter_m, coverage)
        )
    extras = [j for j in range(len(found)) if j not in used]
    return matches, extras


def format_truth_table(matches: Sequence[PipeMatch], extras: Sequence[int], found: Sequence[PipeModel]) -> str:
    """A plain-text table of found vs true pipes, as `gprbot demo` prints it."""
    width = max([20, *(len(m.truth) + 2 for m in matches)])
    head = f"{'pipe':<{width}}{'fill':<11}{'found':>6}{'horiz cm':>10}{'depth cm':>10}{'diam true':>11}"
    head += f"{'diam found':>12}{'diam err':>10}{'coverage':>10}"
    rows = [head, "-" * len(head)]
    for m in matches:
        if m.found is None:
            rows.append(f"{m.truth:<{width}}{m.fill:<11}{'MISSED':>6}")
            continue
        rows.append(
            f"{m.truth:<{width}}{m.fill:<11}{m.found:>6}{100 * m.horizontal_err_m:>10.1f}{100 * m.depth_err_m:>10.1f}"
            f"{100 * m.true_diameter_m:>9.1f}cm{100 * m.found_diameter_m:>10.1f}cm{100 * m.diameter_err_rel:>9.0f}%"
            f"{100 * m.coverage:>9.0f}%"
        )
    for j in extras:
        f = found[j]
        rows.append(
            f"{'(extra)':<{width}}{'':<11}{j:>6}  axis from ({f.axis[0][0]:.2f}, {f.axis[0][1]:.2f}) "
            f"to ({f.axis[-1][0]:.2f}, {f.axis[-1][1]:.2f}) m, depth {f.axis[:, 2].mean():.2f} m, "
            f"diameter {100 * f.diameter_m:.1f} cm"
        )
    return "\n".join(rows)


def within_bounds(
    matches: Sequence[PipeMatch], position_m: float = 0.03, depth_m: float = 0.03, diameter_rel: float = 0.30
) -> bool:
    """True when every truth pipe was found within the foundation issue's error bounds."""
    return all(
        m.found is not None
        and m.horizontal_err_m <= position_m
        and m.depth_err_m <= depth_m
        and abs(m.diameter_err_rel) <= diameter_rel
        for m in matches
    )
