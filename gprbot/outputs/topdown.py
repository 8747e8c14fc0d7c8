"""A top-down map (PNG) of a survey: grid with a scale bar, survey lines, pipes found, and ground truth.

Map convention: x to the right, y up (the site frame seen from above); found pipes are drawn in their
colour (as in the dense PLY) and as wide as their diameter, the truth as grey dashed centre lines.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

from gprbot.atomic_files import write_bytes_atomic
from gprbot.reconstruct.completion import Reconstruction, pipe_colors

MAP_SIDE_PX = 900  # the longer side of the map area
MARGIN_PX = 56
LEGEND_ROW_PX = 18
GRID, LINE_BLUE, TRUTH_GREY, INK = (232, 232, 232), (230, 190, 140), (110, 110, 110), (0, 0, 0)  # BGR
FONT = cv2.FONT_HERSHEY_SIMPLEX
DASH_PX, GAP_PX = 9, 6


def nice_step(span: float, target_count: int) -> float:
    """A 1-2-5 step that divides span into about target_count parts."""
    raw = span / max(target_count, 1)
    power = 10.0 ** math.floor(math.log10(raw))
    return next(power * m for m in (1.0, 2.0, 5.0, 10.0) if power * m >= raw)


class _Canvas:
    """World (x, y) metres → pixel (col, row) for the map area."""

    def __init__(self, extent_xy: tuple[float, float, float, float], legend_rows: int) -> None:
        x0, x1, y0, y1 = extent_xy
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"render_topdown: extent (xmin, xmax, ymin, ymax) is empty: {extent_xy}")
        self.extent = extent_xy
        self.scale = MAP_SIDE_PX / max(x1 - x0, y1 - y0)
        self.width = round((x1 - x0) * self.scale) + 2 * MARGIN_PX
        self.map_height = round((y1 - y0) * self.scale) + 2 * MARGIN_PX
        self.image = np.full((self.map_height + legend_rows * LEGEND_ROW_PX + 8, self.width, 3), 255, np.uint8)

    def px(self, xy: NDArray[np.float64]) -> NDArray[np.int32]:
        """Pixel coordinates (K, 2) of world points (K, ≥2)."""
        x0, _, _, y1 = self.extent
        cols = MARGIN_PX + (xy[:, 0] - x0) * self.scale
        rows = MARGIN_PX + (y1 - xy[:, 1]) * self.scale
        return np.round(np.column_stack([cols, rows])).astype(np.int32)

    def text(self, label: str, at: tuple[int, int], scale: float = 0.42, color: tuple[int, int, int] = INK) -> None:
        """Draw a label with its baseline-left at `at`."""
        cv2.putText(self.image, label, at, FONT, scale, color, 1, cv2.LINE_AA)

    def label(self, label: str, at: tuple[int, int]) -> None:
        """Draw a pipe label, haloed in white so that it reads over lines and pipes."""
        cv2.putText(self.image, label, at, FONT, 0.5, (255, 255, 255), 4, cv2.LINE_AA)
        cv2.putText(self.image, label, at, FONT, 0.5, INK, 1, cv2.LINE_AA)


def _draw_grid(canvas: _Canvas) -> None:
    x0, x1, y0, y1 = canvas.extent
    step = nice_step(max(x1 - x0, y1 - y0), 8)
    for x in np.arange(math.ceil(x0 / step) * step, x1 + 1e-9, step):
        (c, r0), (_, r1) = canvas.px(np.array([[x, y1], [x, y0]]))
        cv2.line(canvas.image, (int(c), int(r0)), (int(c), int(r1)), GRID, 1)
        canvas.text(f"{x:g}", (int(c) - 8, int(r1) + 16), 0.38)
    for y in np.arange(math.ceil(y0 / step) * step, y1 + 1e-9, step):
        (c0, r), (c1, _) = canvas.px(np.array([[x0, y], [x1, y]]))
        cv2.line(canvas.image, (int(c0), int(r)), (int(c1), int(r)), GRID, 1)
        canvas.text(f"{y:g}", (4, int(r) + 4), 0.38)
    canvas.text("x (m)", (canvas.width - MARGIN_PX - 30, canvas.map_height - 8))
    canvas.text("y (m)", (4, MARGIN_PX - 12))


def _draw_scale_bar(canvas: _Canvas) -> None:
    x0, x1, _, _ = canvas.extent
    length = nice_step(x1 - x0, 4)
    left, row = MARGIN_PX, canvas.map_height - 10
    right = left + round(length * canvas.scale)
    cv2.rectangle(canvas.image, (left, row - 5), (right, row), INK, -1)
    canvas.text(f"{length:g} m", (right + 8, row), 0.45)


def _bgr(rgb: NDArray[np.uint8]) -> tuple[int, int, int]:
    """OpenCV's BGR colour for an RGB triple."""
    return int(rgb[2]), int(rgb[1]), int(rgb[0])


def _dashed(image: NDArray[np.uint8], pixels: NDArray[np.int32], color: tuple[int, int, int], width: int) -> None:
    """A dashed polyline whose dash pattern runs on across vertices."""
    phase = 0.0
    for a, b in zip(pixels[:-1].astype(np.float64), pixels[1:].astype(np.float64), strict=True):
        length = float(np.linalg.norm(b - a))
        s = -phase
        while s < length:
            start, stop = max(s, 0.0), min(s + DASH_PX, length)
            if stop > start:
                p, q = a + (b - a) * start / length, a + (b - a) * stop / length
                cv2.line(image, tuple(int(v) for v in np.round(p)), tuple(int(v) for v in np.round(q)), color, width)
            s += DASH_PX + GAP_PX
        phase = (phase + length) % (DASH_PX + GAP_PX)


def render_topdown(
    path: str | os.PathLike[str],
    reconstruction: Reconstruction,
    extent_xy: tuple[float, float, float, float],
    truth_axes: Sequence[NDArray[np.float64]] = (),
    survey_lines: Sequence[NDArray[np.float64]] = (),
) -> None:
    """Write a top-down PNG: grid + scale, survey lines, found pipes in colour, truth grey dashed."""
    pipes = reconstruction.pipes
    canvas = _Canvas(extent_xy, legend_rows=len(pipes) + 1)
    _draw_grid(canvas)
    for line in survey_lines:
        if len(line) >= 2:
            cv2.polylines(canvas.image, [canvas.px(np.asarray(line, np.float64))], False, LINE_BLUE, 1, cv2.LINE_AA)
    colours = pipe_colors(len(pipes))
    for index, pipe in enumerate(pipes):
        bgr = _bgr(colours[index])
        width = max(2, round(pipe.diameter_m * canvas.scale))
        pixels = canvas.px(pipe.axis)
        cv2.polylines(canvas.image, [pixels], False, bgr, width, cv2.LINE_AA)
        end = pixels[-1]
        canvas.label(f"P{index}", (int(end[0]) + width // 2 + 4, int(end[1]) + 4))
    for axis in truth_axes:
        _dashed(canvas.image, canvas.px(np.asarray(axis, np.float64)), TRUTH_GREY, 2)
    _draw_scale_bar(canvas)
    row = canvas.map_height + LEGEND_ROW_PX - 4
    canvas.text("pipe  cover   diameter  confidence  lines   (truth: grey dashed, survey lines: blue)", (8, row))
    for index, pipe in enumerate(pipes):
        row += LEGEND_ROW_PX
        bgr = _bgr(colours[index])
        cv2.rectangle(canvas.image, (8, row - 10), (24, row), bgr, -1)
        summary = (
            f"P{index}  {pipe.depth_of_cover_m:.3f} m  {pipe.diameter_m:.3f} m  {pipe.confidence:.2f}  {pipe.n_slices}"
        )
        canvas.text(summary, (30, row))
    ok, encoded = cv2.imencode(".png", canvas.image)
    if not ok:
        raise ValueError("render_topdown: OpenCV could not encode the map as PNG")
    write_bytes_atomic(path, encoded.tobytes())
