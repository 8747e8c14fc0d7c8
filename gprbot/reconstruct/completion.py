"""The geometric completion — the honest baseline that GPRNet has to beat.

Slices → blobs (one pipe's section per line) → tracks across lines → per pipe an axis polyline and a
radius → tees joined (a pipe whose end runs into another pipe ends on its axis) → a dense cloud sampled
uniformly inside the solid rods over the surveyed extent (from the first to the last line that saw the
pipe, plus half a line spacing).
"""

from __future__ import annotations

import colorsys
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.config import ReconstructionConfig
from gprbot.geometry import closest_points_of_segments, drop_collinear_vertices, drop_repeated_vertices, sample_rods
from gprbot.reconstruct.pipe_fit import SEGMENT_TOLERANCE_M, PipeFit, extend_axis, extension_length, fit_pipe
from gprbot.reconstruct.pipe_track import track_pipes
from gprbot.reconstruct.register import SliceCloud
from gprbot.reconstruct.slice_blobs import SurveyFrame, split_slice, survey_frame

JOIN_MARGIN_M = 0.01  # a pipe end runs into another pipe when its axis passes within R + this of it, ...
JOIN_SLACK_PER_M = 0.05  # ... plus this per metre it was extended (a direction from few centres is a few % off)
JOIN_REACH_LINES = 3.0  # how far past its last sighting (in line spacings) a pipe may still reach another:
# a branch within ~0.15 m of its main hides in the main's hyperbola, two lines on each side of a 60° tee


@dataclass(frozen=True)
class PipeModel:
    """One pipe: axis polyline (site frame, m), radius, depth of cover, diameter, confidence in [0, 1].

    `ends_on` names, for the start and the end of the axis, the index of the pipe it ends on (a tee).
    """

    axis: NDArray[np.float64]
    radius_m: float
    depth_of_cover_m: float
    diameter_m: float
    confidence: float
    n_slices: int
    ends_on: tuple[int | None, int | None] = (None, None)
    pose_std_m: float = 0.0  # RMS 1σ of the antenna positions on the lines that saw it (in `confidence`)
    # axis length (m) at the start and at the end that no line saw: continued there by the completion
    inferred_m: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class Reconstruction:
    """The pipes found, a dense cloud (N, 3) inside them and the pipe index of every dense point."""

    pipes: tuple[PipeModel, ...]
    dense: NDArray[np.float64]
    labels: NDArray[np.intp]


# Ten well-separated colours (Tableau 10 with its grey swapped out: grey is the truth on the map).
_PALETTE = np.array(
    [
        (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
        (140, 86, 75), (227, 119, 194), (0, 128, 128), (188, 189, 34), (23, 190, 207),
    ],
    dtype=np.uint8,
)  # fmt: skip


def pipe_colors(n: int) -> NDArray[np.uint8]:
    """n distinct RGB colours, one per pipe: a fixed palette of ten, then golden-ratio hue steps."""
    extra = [
        colorsys.hsv_to_rgb((0.05 + 0.618033988749895 * i) % 1.0, 0.8, 0.95 if i % 2 else 0.65)
        for i in range(max(0, n - len(_PALETTE)))
    ]
    colours = np.vstack([_PALETTE, np.round(np.array(extra).reshape(-1, 3) * 255.0).astype(np.uint8)])
    return colours[:n]


def _end_joins(
    fits: Sequence[PipeFit], axes: Sequence[NDArray[np.float64]], frame: SurveyFrame
) -> list[list[tuple[int, NDArray[np.float64]] | None]]:
    """For each pipe's start and end: (other pipe, junction point) when its end runs into that pipe."""
    joins: list[list[tuple[int, NDArray[np.float64]] | None]] = []
    for p, fit in enumerate(fits):
        ends: list[tuple[int, NDArray[np.float64]] | None] = []
        for side, point in ((0, fit.inner_axis[0]), (1, fit.inner_axis[-1])):
            outward = fit.outward[side]
            reach = extension_length(outward, JOIN_REACH_LINES * frame.spacing_m, frame)
            ray_end = point + outward * reach
            best: tuple[float, int, NDArray[np.float64]] | None = None
            for q, other in enumerate(axes):
                if q == p:
                    continue
                for a, b in itertools.pairwise(other):
                    s, _, distance = closest_points_of_segments(point, ray_end, a, b)
                    gate = fits[q].radius_m + JOIN_MARGIN_M + JOIN_SLACK_PER_M * s * reach
                    if distance <= gate and (best is None or s < best[0]):
                        best = (s, q, point + s * (ray_end - point))
            ends.append(None if best is None else (best[1], best[2]))
        joins.append(ends)
    return joins


def _pipe_model(axis: NDArray[np.float64], fit: PipeFit, ends_on: tuple[int | None, int | None],
                pose_std_m: float = 0.0) -> PipeModel:
    return PipeModel(
        axis=axis,
        radius_m=fit.radius_m,
        depth_of_cover_m=float(np.min(-axis[:, 2])) - fit.radius_m,
        diameter_m=2.0 * fit.radius_m,
        confidence=fit.confidence * pose_confidence(pose_std_m),
        n_slices=fit.n_slices,
        ends_on=ends_on,
        pose_std_m=pose_std_m,
    )


def pose_confidence(pose_std_m: float) -> float:
    """The share of a pipe's confidence its slices' position uncertainty leaves: a slice placed σ off
    scatters its centre like a fit residual of σ, so it is weighed as the fit weighs residuals."""
    return math.exp(-((pose_std_m / SEGMENT_TOLERANCE_M) ** 2))


def fit_pipes(slices: Sequence[SliceCloud], cfg: ReconstructionConfig) -> list[PipeModel]:
    """Blobs, tracks, fits and tee joins: the pipes seen on at least cfg.min_slices_per_pipe lines."""
    frame = survey_frame(slices)
    seen = [s for s in slices if len(s.points)]
    seen.sort(key=lambda s: float(np.median(frame.offset_of(np.asarray(s.points)))))
    blobs_per_line = [split_slice(order, s, frame) for order, s in enumerate(seen)]
    tracks = track_pipes(blobs_per_line, frame, cfg.cluster_distance_m)
    tracks = [t for t in tracks if len(t) >= max(1, cfg.min_slices_per_pipe)]
    tracks.sort(key=lambda t: (t[0].offset, t[0].along))
    fits = [fit_pipe(t, frame) for t in tracks]
    half = 0.5 * frame.spacing_m
    axes = [
        extend_axis(
            f.inner_axis,
            f.outward,
            (extension_length(f.outward[0], half, frame), extension_length(f.outward[1], half, frame)),
        )
        for f in fits
    ]
    joins = _end_joins(fits, axes, frame)
    line_std = {s.line: s.pose_std_m for s in seen}
    pipes = []
    for track, fit, axis, (start, end) in zip(tracks, fits, axes, joins, strict=True):
        pose_std = float(np.sqrt(np.mean([line_std.get(b.line, 0.0) ** 2 for b in track])))
        first = start[1] if start is not None else axis[0]
        last = end[1] if end is not None else axis[-1]
        joined = drop_collinear_vertices(drop_repeated_vertices(np.vstack([first, fit.inner_axis, last])))
        ends_on = (start[0] if start else None, end[0] if end else None)
        pipes.append(_pipe_model(joined, fit, ends_on, pose_std))
    return pipes


def geometric_completion(
    slices: Sequence[SliceCloud], cfg: ReconstructionConfig, rng: np.random.Generator
) -> Reconstruction:
    """Complete registered slices into pipes and a dense cloud of cfg.dense_points points inside them."""
    pipes = fit_pipes(slices, cfg)
    dense, labels = sample_rods([p.axis for p in pipes], [p.radius_m for p in pipes], cfg.dense_points, rng)
    return Reconstruction(pipes=tuple(pipes), dense=dense, labels=labels)
