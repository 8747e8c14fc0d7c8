"""Link blobs across neighbouring survey lines into pipes: a predict-and-assign tracker.

Lines are visited in cross-track order. Each open track predicts where its pipe crosses the next line
— from its last two crossings, or, with only one, from the blob's shape (an oblique pipe's section is
1/sin φ wider than tall) — and a global assignment (Hungarian) matches predictions to blobs, gated on
along-track distance, depth and blob height. A blob that two tracks predict into is split between them.
Tracks seen fewer than three times may not skip a line; a last pass stitches tracks broken by missed
lines where the straight continuation of each meets the other.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from gprbot.reconstruct.slice_blobs import Blob, SurveyFrame, make_blob

MIN_CROSSING_DEG = 25.0  # pipes cross the lines at ≥ ~30°; a little slack for noise
MAX_COT = 1.0 / math.tan(math.radians(MIN_CROSSING_DEG))
# A bend of up to 45° between two lines moves the crossing by up to ~1.15× the line gap from where the
# previous direction predicts it (cot 30° − cot 60°); with a margin:
TURN_GATE_PER_M = 1.25
DEPTH_GATE_M = 0.03
DEPTH_GATE_PER_M = 0.3
HEIGHT_GATE_FRACTION = 0.35
# A track seen once is most often speckle, so its first link has tighter gates: a pipe's section
# predicts its next crossing well from its shape, and slopes stay < ~15 %. Its size less so: one pipe's
# sections from the classical interpreter differ by up to ~30 % between lines (a tee's branch beside
# its main: 4.2 and 5.6 cm), so the height gate is a quarter of the larger height.
FIRST_LINK_GATE_FRACTION = 0.5  # of cluster_distance_m
SHAPE_GATE_PER_M = 0.4
# The section's width/height against the truth's 1/sin(crossing): rms 0.27 over 1,035 sections on the 100
# validation surveys (classical interpretation). The crossing's cotangent is taken over ratio ± this, so the
# first link's gate spans every angle the section's shape allows (a validation tee's 45° branch is now linked).
SHAPE_RATIO_STD = 0.27
FIRST_LINK_DEPTH_GATE_M = 0.01
FIRST_LINK_DEPTH_GATE_PER_M = 0.15
FIRST_LINK_HEIGHT_FRACTION = 0.25
MAX_MISSED_LINES = 2
ONE_SIGHTING_PENALTY = 0.3  # prefer continuing established tracks over tracks seen once
MISS_PENALTY = 0.5  # per missed line
# Stitching tracks across missed lines: a straight continuation, checked from both sides.
STITCH_GATE_FRACTION = 0.5  # of cluster_distance_m
STITCH_GATE_PER_M = 0.5
STITCH_DEPTH_GATE_M = 0.02
STITCH_DEPTH_GATE_PER_M = 0.1
STITCH_HEIGHT_FRACTION = 0.25
SPLIT_ITERATIONS = 8
_INFEASIBLE = 1e9


@dataclass
class Track:
    """A pipe being followed: its blobs in cross-track order."""

    blobs: list[Blob] = field(default_factory=list)


@dataclass(frozen=True)
class Prediction:
    """Where a track expects its pipe on a line: candidate along-track positions, depth, size, gates."""

    along: tuple[float, ...]
    z: float
    height: float
    gate_along: float
    gate_z: float
    height_fraction: float  # the height gate: this fraction of the larger of the two heights, ...
    height_pad: float  # ... plus this (pixels)
    penalty: float
    established: bool


def predict(track: Track, offset: float, frame: SurveyFrame, cluster_distance_m: float) -> Prediction:
    """Predict the crossing of a track's pipe with the line at cross-track `offset`."""
    last = track.blobs[-1]
    gap = abs(offset - last.offset)
    height = float(np.median([b.height_m for b in track.blobs]))
    missed = max(0.0, gap / frame.spacing_m - 1.0)
    gate_z = DEPTH_GATE_M + DEPTH_GATE_PER_M * gap
    if len(track.blobs) >= 2:
        step = last.centre - track.blobs[-2].centre
        step_across = float(frame.offset_of(step))
        if abs(step_across) > 1e-6:
            t = (offset - last.offset) / step_across
            shift = float(np.clip(t * float(frame.along_of(step)), -MAX_COT * gap, MAX_COT * gap))
            return Prediction(
                along=(last.along + shift,),
                z=float(last.centre[2] + t * step[2]),
                height=height,
                gate_along=cluster_distance_m + TURN_GATE_PER_M * gap,
                gate_z=gate_z,
                height_fraction=HEIGHT_GATE_FRACTION,
                height_pad=2.0 * last.pitch[1],
                penalty=MISS_PENALTY * missed,
                established=True,
            )
    ratio = last.width_m / max(last.height_m, 1e-6)
    cot_low, cot_high = (_cot_of_ratio(ratio - SHAPE_RATIO_STD), _cot_of_ratio(ratio + SHAPE_RATIO_STD))
    cot, cot_spread = 0.5 * (cot_low + cot_high), 0.5 * (cot_high - cot_low)
    return Prediction(
        along=(last.along - cot * gap, last.along + cot * gap),
        z=float(last.centre[2]),
        height=height,
        gate_along=FIRST_LINK_GATE_FRACTION * cluster_distance_m + (SHAPE_GATE_PER_M + cot_spread) * gap,
        gate_z=FIRST_LINK_DEPTH_GATE_M + FIRST_LINK_DEPTH_GATE_PER_M * gap,
        height_fraction=FIRST_LINK_HEIGHT_FRACTION,
        height_pad=0.5 * last.pitch[1],
        penalty=ONE_SIGHTING_PENALTY + MISS_PENALTY * missed,
        established=False,
    )


def _cot_of_ratio(ratio: float) -> float:
    """The crossing's cotangent from a section's width/height (an oblique pipe's is 1/sin wider than tall)."""
    return min(math.sqrt(max(ratio * ratio - 1.0, 0.0)), MAX_COT)


def match_cost(prediction: Prediction, blob: Blob) -> float:
    """Normalised squared residual of a blob against a prediction; _INFEASIBLE outside the gates.

    The height gate is a fraction of the larger height, so that linking two sections does not depend
    on which of them the track saw first.
    """
    gate_height = prediction.height_fraction * max(prediction.height, blob.height_m) + prediction.height_pad
    ratios = (
        min(abs(blob.along - a) for a in prediction.along) / prediction.gate_along,
        abs(float(blob.centre[2]) - prediction.z) / prediction.gate_z,
        abs(blob.height_m - prediction.height) / gate_height,
    )
    if max(ratios) > 1.0:
        return _INFEASIBLE
    return sum(r * r for r in ratios) + prediction.penalty


def split_merged(blob: Blob, predictions: Sequence[Prediction], frame: SurveyFrame) -> list[Blob]:
    """Split a blob that several established tracks predict into, by nearest predicted centre (k-means)."""
    along = frame.along_of(blob.points)
    coords = np.column_stack([along, blob.points[:, 2]])
    pad_along, pad_z = blob.pitch[0] + 1e-6, blob.pitch[1] + 1e-6
    seeds = [
        (p.along[0], p.z)
        for p in predictions
        if p.established
        and along.min() - pad_along <= p.along[0] <= along.max() + pad_along
        and blob.points[:, 2].min() - pad_z <= p.z <= blob.points[:, 2].max() + pad_z
    ]
    if len(seeds) < 2:
        return [blob]
    centres = np.array(seeds)
    labels = np.zeros(len(coords), dtype=np.intp)
    for _ in range(SPLIT_ITERATIONS):
        labels = np.argmin(np.linalg.norm(coords[:, None, :] - centres[None, :, :], axis=2), axis=1)
        centres = np.array(
            [coords[labels == k].mean(axis=0) if np.any(labels == k) else centres[k] for k in range(len(centres))]
        )
    parts = [blob.points[labels == k] for k in range(len(centres))]
    if min(len(p) for p in parts) < 3:
        return [blob]
    return [make_blob(blob.order, blob.line, part, frame, blob.pitch) for part in parts]


def _horizon(track: Track, frame: SurveyFrame) -> float:
    """How far across the lines a track may go unseen before it ends (short tracks: not at all)."""
    missed = MAX_MISSED_LINES if len(track.blobs) >= 3 else 0
    return (missed + 1.5) * frame.spacing_m


def _extrapolate(blobs: Sequence[Blob], offset: float, frame: SurveyFrame) -> tuple[float, float] | None:
    """(along, z) where the straight continuation of the last two blobs crosses the line at offset."""
    if len(blobs) < 2:
        return None
    step = blobs[-1].centre - blobs[-2].centre
    step_across = float(frame.offset_of(step))
    if abs(step_across) < 1e-6:
        return None
    t = (offset - blobs[-1].offset) / step_across
    return blobs[-1].along + t * float(frame.along_of(step)), float(blobs[-1].centre[2] + t * step[2])


def stitch_cost(
    first: Sequence[Blob], second: Sequence[Blob], frame: SurveyFrame, cluster_distance_m: float
) -> float | None:
    """How well `second` continues `first` straight across missed lines (both ways); None: it does not."""
    gap = second[0].offset - first[-1].offset
    if not 0.5 * frame.spacing_m < gap <= (MAX_MISSED_LINES + 1.5) * frame.spacing_m:
        return None
    h1, h2 = float(np.median([b.height_m for b in first])), float(np.median([b.height_m for b in second]))
    if abs(h1 - h2) > STITCH_HEIGHT_FRACTION * max(h1, h2) + 0.5 * first[-1].pitch[1]:
        return None
    checks = [
        (_extrapolate(first, second[0].offset, frame), second[0]),
        (_extrapolate(second[::-1], first[-1].offset, frame), first[-1]),
    ]
    total, used = 0.0, 0
    for predicted, blob in checks:
        if predicted is None:
            continue
        along = abs(blob.along - predicted[0]) / (STITCH_GATE_FRACTION * cluster_distance_m + STITCH_GATE_PER_M * gap)
        depth = abs(float(blob.centre[2]) - predicted[1]) / (STITCH_DEPTH_GATE_M + STITCH_DEPTH_GATE_PER_M * gap)
        if max(along, depth) > 1.0:
            return None
        total, used = total + along**2 + depth**2, used + 1
    return total if used else None


def stitch_tracks(tracks: list[list[Blob]], frame: SurveyFrame, cluster_distance_m: float) -> list[list[Blob]]:
    """Join tracks broken by missed lines where each one's straight continuation meets the other."""
    tracks = [list(t) for t in tracks]
    while True:
        best: tuple[float, int, int] | None = None
        for i, first in enumerate(tracks):
            for j, second in enumerate(tracks):
                cost = None if i == j else stitch_cost(first, second, frame, cluster_distance_m)
                if cost is not None and (best is None or cost < best[0]):
                    best = (cost, i, j)
        if best is None:
            return tracks
        _, i, j = best
        tracks[i] = tracks[i] + tracks[j]
        del tracks[j]


def track_pipes(
    blobs_per_line: Sequence[Sequence[Blob]], frame: SurveyFrame, cluster_distance_m: float
) -> list[list[Blob]]:
    """Link the blobs of lines (given in cross-track order) into tracks; returns each track's blobs."""
    open_tracks: list[Track] = []
    closed: list[Track] = []
    for line_blobs in blobs_per_line:
        if not line_blobs:
            continue
        offset = float(np.median([b.offset for b in line_blobs]))
        still_open = [t for t in open_tracks if offset - t.blobs[-1].offset <= _horizon(t, frame)]
        closed += [t for t in open_tracks if offset - t.blobs[-1].offset > _horizon(t, frame)]
        open_tracks = still_open
        predictions = [predict(t, offset, frame, cluster_distance_m) for t in open_tracks]
        blobs = [part for blob in line_blobs for part in split_merged(blob, predictions, frame)]
        matched_blobs: set[int] = set()
        if open_tracks:
            cost = np.array([[match_cost(p, b) for b in blobs] for p in predictions])
            for row, col in zip(*linear_sum_assignment(cost), strict=True):
                if cost[row, col] < _INFEASIBLE:
                    open_tracks[row].blobs.append(blobs[col])
                    matched_blobs.add(int(col))
        open_tracks += [Track([b]) for i, b in enumerate(blobs) if i not in matched_blobs]
    return stitch_tracks([t.blobs for t in closed + open_tracks], frame, cluster_distance_m)
