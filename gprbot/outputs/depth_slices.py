"""Depth slices (C-scans): the migrated amplitude of all lines, per depth band, as maps of the site.

Each line's migrated envelope is reduced to its maximum within a depth band at every column, placed at
the column's site position, and interpolated between lines (linearly, inside the lines' hull only —
nothing is drawn where no line passed). All bands share one colour scale so that a weak deep band
looks weak; the pipes found are drawn over each band they cross.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import LinearNDInterpolator, griddata
from scipy.spatial import Delaunay, QhullError

from gprbot.gpr.migration import envelope
from gprbot.plotting import new_figure, save_png
from gprbot.reconstruct.completion import pipe_colors
from gprbot.reconstruct.survey_result import SurveyResult

GRID_STEP_M = 0.02


@dataclass(frozen=True)
class DepthSlice:
    """One band's map: (ny, nx) amplitude on a site grid (NaN outside the surveyed hull)."""

    top_m: float
    bottom_m: float
    x_m: NDArray[np.float64]
    y_m: NDArray[np.float64]
    amplitude: NDArray[np.float64]


def depth_bands(depth_max_m: float, count: int = 6) -> list[tuple[float, float]]:
    """`count` equal bands from the surface to depth_max_m."""
    edges = np.linspace(0.0, depth_max_m, count + 1)
    return [(float(a), float(b)) for a, b in itertools.pairwise(edges)]


def depth_slices(result: SurveyResult, bands: Sequence[tuple[float, float]],
                 extent_xy: tuple[float, float, float, float]) -> list[DepthSlice]:
    """The survey's migrated amplitude per depth band, gridded over extent_xy (xmin, xmax, ymin, ymax)."""
    x0, x1, y0, y1 = extent_xy
    gx = np.arange(x0, x1 + GRID_STEP_M / 2, GRID_STEP_M)
    gy = np.arange(y0, y1 + GRID_STEP_M / 2, GRID_STEP_M)
    mesh_x, mesh_y = np.meshgrid(gx, gy)
    positions = []
    envelopes = []
    for lr in result.lines:
        positions.append(lr.bscan.position_at(lr.section.x_m)[:, :2])
        envelopes.append((np.asarray(lr.section.z_m, np.float64), np.asarray(envelope(lr.section.image), np.float64)))
    points = np.concatenate(positions) if positions else np.zeros((0, 2))
    triangulation = None
    if len(result.lines) >= 2 and len(points) >= 4:
        try:  # one triangulation for every band: only the values change
            triangulation = Delaunay(points)
        except QhullError:  # lines on top of each other: no area to interpolate over
            triangulation = None
    slices = []
    for top, bottom in bands:
        values = []
        for (z, env) in envelopes:
            rows = (z >= top) & (z < bottom)
            values.append(env[rows].max(axis=0) if rows.any() else np.full(env.shape[1], np.nan))
        amplitude = np.concatenate(values) if values else np.zeros(0)
        keep = np.isfinite(amplitude)
        if triangulation is not None:
            grid = LinearNDInterpolator(triangulation, amplitude)(mesh_x, mesh_y)
        elif keep.any():  # one line: show the line itself
            grid = griddata(points[keep], amplitude[keep], (mesh_x, mesh_y), method="nearest")
        else:
            grid = np.full(mesh_x.shape, np.nan)
        slices.append(DepthSlice(top, bottom, gx, gy, np.asarray(grid, np.float64)))
    return slices


def render_depth_slices(path: str | os.PathLike[str], result: SurveyResult, slices: Sequence[DepthSlice],
                        velocity_note: str) -> None:
    """A grid of depth-slice maps (x right, y up, true scale), one colour scale, pipes drawn where they cross."""
    columns = 3 if len(slices) > 4 else max(len(slices), 1)
    rows = -(-len(slices) // columns)
    aspect = (np.ptp(slices[0].y_m) / max(np.ptp(slices[0].x_m), 1e-6)) if slices else 1.0
    panel_in, left_in, right_in, bottom_in, top_in, gap_in = 4.0, 0.7, 1.3, 0.55, 0.55, 0.45
    width_in = left_in + columns * panel_in + (columns - 1) * 0.25 + right_in
    height_in = bottom_in + rows * panel_in * float(aspect) + (rows - 1) * gap_in + top_in
    fig = new_figure((width_in, height_in), fixed_layout=True)  # one draw: this picture is made for every run
    finite = np.concatenate([s.amplitude[np.isfinite(s.amplitude)] for s in slices]) if slices else np.zeros(0)
    vmax = float(np.percentile(finite, 99.5)) if finite.size else 1.0
    colours = pipe_colors(max(len(result.reconstruction.pipes), 1)) / 255.0
    axes = fig.subplots(rows, columns, squeeze=False, sharex=True, sharey=True, gridspec_kw={
        "left": left_in / width_in, "right": 1 - right_in / width_in, "bottom": bottom_in / height_in,
        "top": 1 - top_in / height_in, "wspace": 0.25 / panel_in, "hspace": gap_in / (panel_in * float(aspect))})
    image = None
    for ax, sl in zip(axes.flat, slices, strict=False):
        image = ax.imshow(sl.amplitude, origin="lower", cmap="inferno", vmin=0.0, vmax=vmax or 1.0,
                          extent=(sl.x_m[0], sl.x_m[-1], sl.y_m[0], sl.y_m[-1]), interpolation="nearest")
        for lr in result.lines:
            xy = lr.bscan.positions[:: max(len(lr.bscan.positions) // 50, 1), :2]  # 50 points draw a line
            ax.plot(xy[:, 0], xy[:, 1], color="#8cb4e6", linewidth=0.5)
        for index, pipe in enumerate(result.reconstruction.pipes):
            centre_top = pipe.depth_of_cover_m
            if centre_top < sl.bottom_m and centre_top + pipe.diameter_m > sl.top_m:
                ax.plot(pipe.axis[:, 0], pipe.axis[:, 1], "--", color=colours[index], linewidth=1.2)
        ax.set_title(f"depth {sl.top_m:.2f}–{sl.bottom_m:.2f} m", fontsize=9)
        ax.set_aspect("equal")
    for ax in axes.flat[len(slices):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("site x (m)")
    for ax in axes[:, 0]:
        ax.set_ylabel("site y (m)")
    if image is not None:
        bar_ax = fig.add_axes((1 - (right_in - 0.2) / width_in, bottom_in / height_in, 0.18 / width_in,
                               1 - (bottom_in + top_in) / height_in))
        bar = fig.colorbar(image, cax=bar_ax)
        bar.set_label("max migrated envelope in the band (one scale for all bands)")
    fig.suptitle(f"Depth slices of {len(result.lines)} lines (migrated at v = {result.velocity_m_per_ns:.4f} m/ns, "
                 f"{velocity_note}); dashed: pipes found in the band, blue: survey lines", fontsize=10)
    save_png(fig, path)
