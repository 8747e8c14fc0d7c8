"""Blobs: the connected pieces of one slice's mask pixels — each one pipe's cross-section in that line.

Everything here is expressed in the survey frame: `along` is the coordinate along the survey lines,
`offset` the cross-track coordinate that orders the lines, z the site vertical.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from gprbot.reconstruct.register import SliceCloud

BLOB_LINK_M = 0.02  # mask pixels closer than this belong to the same blob
# ... or closer than this many pixel pitches. A slice's columns sit at its traces' registered positions, which
# pose noise spaces unevenly (one validation line: gaps of 1 to 26 mm at a 15 mm pitch), and a dropped trace
# leaves a gap of two pitches: at 1.5 pitches one pipe's section fell apart into side-by-side strips on a line
# (100 validation surveys: 90 extra pipes, 69 of them pieces along a pipe found already); at 2.5, 24 extras
# and 3 more pipes found.
BLOB_LINK_PITCHES = 2.5
MIN_BLOB_POINTS = 3  # smaller blobs are speckle, not a pipe
MIN_CORE_NEIGHBOURS = 4  # inside a pipe's section a pixel has ~10–25 neighbours within the link distance
DEFAULT_SPACING_M = 0.1  # line spacing assumed when fewer than two lines saw anything


@dataclass(frozen=True)
class SurveyFrame:
    """The survey's axes: unit along-track and cross-track (left of along) vectors, and line spacing."""

    along: NDArray[np.float64]
    across: NDArray[np.float64]
    spacing_m: float

    def along_of(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """Along-track coordinates of site-frame points (M, 3) or (3,)."""
        return np.asarray(points[..., :2] @ self.along, dtype=np.float64)

    def offset_of(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """Cross-track coordinates of site-frame points (M, 3) or (3,)."""
        return np.asarray(points[..., :2] @ self.across, dtype=np.float64)


@dataclass(frozen=True)
class Blob:
    """One connected piece of a slice: its points, centre and in-plane size (equivalent ellipse axes)."""

    order: int  # rank of its slice in cross-track order
    line: int
    points: NDArray[np.float64]
    centre: NDArray[np.float64]
    offset: float
    along: float
    width_m: float  # along-track diameter of the equivalent filled ellipse
    height_m: float  # vertical diameter of the equivalent filled ellipse
    pitch: tuple[float, float]  # (along, vertical) pixel pitch of its slice


def _pitch(values: NDArray[np.float64]) -> float:
    """Estimated grid step of pixel coordinates: a low quantile of the gaps between distinct values.

    A low quantile, not the median: speckle scattered over the image adds many large gaps.
    """
    distinct = np.unique(np.round(values, 6))
    if len(distinct) < 2:
        return 0.0
    return float(np.quantile(np.diff(distinct), 0.25))


def make_blob(
    order: int, line: int, points: NDArray[np.float64], frame: SurveyFrame, pitch: tuple[float, float]
) -> Blob:
    """A Blob from its points, with its in-plane width and height as an equivalent filled ellipse's."""
    along = frame.along_of(points)
    centre = points.mean(axis=0)
    # Sizes from second moments, not extents: a filled ellipse of semi-axis a has variance a²/4, and
    # pixelation adds pitch²/12. Extents jump by a whole pixel with the grid phase; moments do not.
    var_along = max(float(np.var(along)) - pitch[0] ** 2 / 12.0, 0.0)
    var_z = max(float(np.var(points[:, 2])) - pitch[1] ** 2 / 12.0, 0.0)
    return Blob(
        order=order,
        line=line,
        points=points,
        centre=centre,
        offset=float(frame.offset_of(centre)),
        along=float(frame.along_of(centre)),
        width_m=4.0 * float(np.sqrt(var_along)),
        height_m=4.0 * float(np.sqrt(var_z)),
        pitch=pitch,
    )


def survey_frame(slices: Sequence[SliceCloud]) -> SurveyFrame:
    """The survey frame from the lines' directions (boustrophedon signs aligned) and their offsets."""
    directions = [np.asarray(s.direction, dtype=np.float64) for s in slices]
    reference = directions[0] if directions else np.array([1.0, 0.0])
    aligned = [d if float(d @ reference) >= 0.0 else -d for d in directions] or [reference]
    along = np.mean(aligned, axis=0)
    along = along / np.linalg.norm(along)
    across = np.array([-along[1], along[0]])
    offsets = sorted(float(np.median(s.points[:, :2] @ across)) for s in slices if len(s.points))
    gaps = np.diff(offsets)
    gaps = gaps[gaps > 1e-3]
    spacing = float(np.min(gaps)) if len(gaps) else DEFAULT_SPACING_M
    # The smallest gap, not the median: a missing line doubles a gap but never halves one. Guard against
    # a repeated line at nearly the same offset by requiring a gap of at least a quarter of the median.
    if len(gaps) >= 2:
        spacing = float(np.min(gaps[gaps >= 0.25 * np.median(gaps)]))
    return SurveyFrame(along=along, across=across, spacing_m=spacing)


def cluster_points(points: NDArray[np.float64], link_m: float) -> NDArray[np.intp]:
    """Blob label per point (−1: speckle), linking points within link_m (DBSCAN-like).

    Only core points — with at least MIN_CORE_NEIGHBOURS within link_m — link blobs together; the other
    points join their nearest core point's blob. So a stray pixel between two pipes cannot bridge them,
    and a speckle with no core point disappears.
    """
    pairs = cKDTree(points).query_pairs(r=link_m, output_type="ndarray")
    n = len(points)
    neighbours = np.bincount(pairs.ravel(), minlength=n)
    core = neighbours >= MIN_CORE_NEIGHBOURS
    labels = np.full(n, -1, dtype=np.intp)
    if not np.any(core):
        return labels
    core_pairs = pairs[core[pairs[:, 0]] & core[pairs[:, 1]]]
    graph = coo_matrix((np.ones(len(core_pairs)), (core_pairs[:, 0], core_pairs[:, 1])), shape=(n, n))
    _, components = connected_components(graph, directed=False)
    core_index = np.flatnonzero(core)
    labels[core_index] = components[core_index]
    border = np.flatnonzero(~core)
    if len(border):
        distance, nearest = cKDTree(points[core_index]).query(points[border], distance_upper_bound=link_m)
        attached = np.isfinite(distance)
        labels[border[attached]] = labels[core_index[nearest[attached]]]
    return labels


def split_slice(order: int, cloud: SliceCloud, frame: SurveyFrame) -> list[Blob]:
    """The blobs of one slice: points linked within max(2 cm, 2.5 pixel pitches), speckle dropped."""
    points = np.asarray(cloud.points, dtype=np.float64)
    if len(points) < MIN_BLOB_POINTS:
        return []
    pitch = cloud.pixel_pitch_m or (_pitch(frame.along_of(points)), _pitch(points[:, 2]))
    labels = cluster_points(points, max(BLOB_LINK_M, BLOB_LINK_PITCHES * max(pitch)))
    blobs = []
    for label in np.unique(labels[labels >= 0]):
        members = points[labels == label]
        if len(members) >= MIN_BLOB_POINTS:
            blobs.append(make_blob(order, cloud.line, members, frame, pitch))
    return sorted(blobs, key=lambda b: b.along)
