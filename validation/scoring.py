"""Scoring one interpreted B-scan against its truth: matches within 3 and 1 cm, radius, false pipes.

A truth target is found when a detection lies within the tolerance in both x and centre depth; each
detection matches at most one target (nearest first). A detection is a false pipe when it is reported
as a pipe and matches no pipe: one that lies on a rebar and is reported as a rebar is not false, one on
a rebar reported as a pipe is. Rebars are scored the same way on their own.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

TOLERANCE_M = 0.03
FINE_TOLERANCE_M = 0.01
RADIUS_TOLERANCE = 0.3


@dataclass(frozen=True)
class Target:
    """A true target: along-track x and centre depth (m), radius (m; None: not known)."""

    x_m: float
    depth_m: float | None
    radius_m: float | None
    kind: str  # "pipe" or "rebar"


@dataclass(frozen=True)
class Found:
    """A detection as the scorer sees it."""

    x_m: float
    depth_m: float
    radius_m: float
    kind: str
    radius_measured: bool = False  # the method says its data measure this radius (not a default or a blob's size)


@dataclass(frozen=True)
class Score:
    """Counts for one B-scan."""

    pipes: int
    pipes_within: int
    pipes_within_fine: int
    radius_ok: int
    tops_within_fine: int  # x and the top's depth (centre less radius) within 1 cm: what a hyperbola's apex shows
    false_pipes: int
    rebars: int
    rebars_found: int  # found within tolerance and reported as rebar
    false_rebars: int
    tops_within: int = 0  # x and the top's depth within the tolerance: found, whatever the radius says of the centre
    radius_claimed: int = 0  # pipes found within tolerance whose radius the method says it measured
    radius_claimed_ok: int = 0  # ... and that radius within 30 %: whether the claim holds


def _near(d: Found, t: Target, tol: float, tol_depth: float | None = None) -> bool:
    """Whether a detection lies within the tolerance of a target (x, and depth when known)."""
    if abs(d.x_m - t.x_m) > tol:
        return False
    return t.depth_m is None or abs(d.depth_m - t.depth_m) <= (tol if tol_depth is None else tol_depth)


def match(found: Sequence[Found], truth: Sequence[Target], tol: float) -> dict[int, int]:
    """Greedy one-to-one matching, nearest pairs first: {truth index: detection index}."""
    pairs = sorted(
        ((abs(d.x_m - t.x_m) + (0.0 if t.depth_m is None else abs(d.depth_m - t.depth_m)), i, j)
         for i, t in enumerate(truth) for j, d in enumerate(found) if _near(d, t, tol)),
    )
    out: dict[int, int] = {}
    used: set[int] = set()
    for _, i, j in pairs:
        if i not in out and j not in used:
            out[i] = j
            used.add(j)
    return out


def score(found: Sequence[Found], truth: Sequence[Target], tol: float = TOLERANCE_M) -> Score:
    """Score detections against the truth (tolerance `tol` for 'within', 1 cm for 'within fine')."""
    pipes = [t for t in truth if t.kind == "pipe"]
    bars = [t for t in truth if t.kind == "rebar"]
    on_pipe = match(found, pipes, tol)
    fine = match(found, pipes, min(tol, FINE_TOLERANCE_M))
    radius_right = {
        i for i, j in on_pipe.items()
        if pipes[i].radius_m and abs(found[j].radius_m - pipes[i].radius_m) <= RADIUS_TOLERANCE * pipes[i].radius_m
    }
    claimed = {i for i, j in on_pipe.items() if pipes[i].radius_m and found[j].radius_measured}
    found_tops = [replace(d, depth_m=d.depth_m - d.radius_m) for d in found]
    true_tops = [replace(t, depth_m=None if t.depth_m is None or t.radius_m is None else t.depth_m - t.radius_m)
                 for t in pipes]
    tops = match(found_tops, true_tops, min(tol, FINE_TOLERANCE_M))
    rest = [j for j in range(len(found)) if j not in set(on_pipe.values())]
    on_bar = match([found[j] for j in rest], bars, tol)
    bar_hits = {rest[j] for j in on_bar.values()}
    false_pipes = sum(1 for j in rest if found[j].kind == "pipe")
    rebars_found = sum(1 for j in bar_hits if found[j].kind == "rebar")
    false_rebars = sum(1 for j in rest if found[j].kind == "rebar" and j not in bar_hits)
    return Score(len(pipes), len(on_pipe), len(fine), len(radius_right), len(tops), false_pipes, len(bars),
                 rebars_found, false_rebars, len(match(found_tops, true_tops, tol)), len(claimed),
                 len(claimed & radius_right))
