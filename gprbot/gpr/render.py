"""PNG pictures of B-scans and cross-sections (cv2), with axes, scales and the detections drawn.

Colours (BGR): the cross-section mask's outline is green, the truth mask's (if given) red, and each
detection a yellow cross with its depth and radius.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from gprbot.atomic_files import write_bytes_atomic
from gprbot.errors import DataFormatError
from gprbot.gpr.bscan import BScan, CrossSection
from gprbot.gpr.migration import envelope

_MARGIN_LEFT, _MARGIN_BOTTOM, _MARGIN_TOP, _MARGIN_RIGHT = 70, 50, 30, 20
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_WHITE, _GREEN, _RED, _YELLOW = (255, 255, 255), (0, 200, 0), (0, 0, 255), (0, 220, 255)
_MAGENTA = (255, 0, 255)
_TARGET_WIDTH, _TARGET_HEIGHT = 900, 500


def _grey(values: NDArray[np.floating], symmetric: bool) -> NDArray[np.uint8]:
    """Values as an 8-bit image: symmetric (mid-grey zero) or 0..max, clipped at the 99.5th percentile."""
    v = np.asarray(values, dtype=np.float64)
    scale = float(np.percentile(np.abs(v), 99.5)) or 1.0
    scaled = 128.0 + 127.0 * v / scale if symmetric else 255.0 * np.abs(v) / scale
    return np.clip(scaled, 0, 255).astype(np.uint8)


def _nice_step(span: float, ticks: int = 6) -> float:
    """A 1-2-5 tick step giving about `ticks` ticks over span."""
    raw = max(span, 1e-12) / ticks
    power = 10.0 ** math.floor(math.log10(raw))
    return next(m * power for m in (1.0, 2.0, 5.0, 10.0) if m * power >= raw)


def _framed(
    image: NDArray[np.uint8], x_range: tuple[float, float], y_range: tuple[float, float],
    x_label: str, y_label: str, title: str,
) -> tuple[NDArray[np.uint8], tuple[float, float, float, float]]:
    """Resize the picture to a readable size and add axes with ticks; returns it and the pixel mapping.

    The mapping (x_scale, x_offset, y_scale, y_offset) turns data coordinates into canvas pixels.
    """
    h, w = image.shape[:2]
    width = max(w, min(_TARGET_WIDTH, 4 * w))
    height = max(h, min(_TARGET_HEIGHT, 4 * h))
    body = cv2.resize(image, (width, height), interpolation=cv2.INTER_NEAREST)
    if body.ndim == 2:
        body = cv2.cvtColor(body, cv2.COLOR_GRAY2BGR)
    canvas = np.zeros((height + _MARGIN_TOP + _MARGIN_BOTTOM, width + _MARGIN_LEFT + _MARGIN_RIGHT, 3), np.uint8)
    canvas[_MARGIN_TOP : _MARGIN_TOP + height, _MARGIN_LEFT : _MARGIN_LEFT + width] = body
    (x0, x1), (y0, y1) = x_range, y_range
    sx = width / max(x1 - x0, 1e-12)
    sy = height / max(y1 - y0, 1e-12)
    mapping = (sx, _MARGIN_LEFT - x0 * sx, sy, _MARGIN_TOP - y0 * sy)
    step = _nice_step(x1 - x0)
    for tick in np.arange(math.ceil(x0 / step) * step, x1 + 1e-9, step):
        px = round(mapping[0] * tick + mapping[1])
        cv2.line(canvas, (px, _MARGIN_TOP + height), (px, _MARGIN_TOP + height + 6), _WHITE, 1)
        cv2.putText(canvas, f"{tick:g}", (px - 12, _MARGIN_TOP + height + 22), _FONT, 0.45, _WHITE, 1)
    step = _nice_step(y1 - y0)
    for tick in np.arange(math.ceil(y0 / step) * step, y1 + 1e-9, step):
        py = round(mapping[2] * tick + mapping[3])
        cv2.line(canvas, (_MARGIN_LEFT - 6, py), (_MARGIN_LEFT, py), _WHITE, 1)
        cv2.putText(canvas, f"{tick:g}", (4, py + 5), _FONT, 0.45, _WHITE, 1)
    cv2.putText(canvas, x_label, (_MARGIN_LEFT + width // 2 - 40, canvas.shape[0] - 8), _FONT, 0.5, _WHITE, 1)
    cv2.putText(canvas, y_label, (4, _MARGIN_TOP - 10), _FONT, 0.5, _WHITE, 1)
    cv2.putText(canvas, title, (_MARGIN_LEFT + 60, _MARGIN_TOP - 10), _FONT, 0.5, _WHITE, 1)
    return canvas, mapping


def _write(path: str | Path, canvas: NDArray[np.uint8]) -> None:
    """Encode a PNG and write it atomically (like every other output), errors naming the path."""
    target = Path(path)
    try:
        ok, encoded = cv2.imencode(".png", canvas)
    except cv2.error as exc:
        raise DataFormatError(f"cannot encode PNG {target}: {exc}") from exc
    if not ok:
        raise DataFormatError(f"cannot encode PNG {target}")
    try:
        write_bytes_atomic(target, encoded.tobytes())
    except OSError as exc:
        raise DataFormatError(f"cannot write PNG {target}: {exc.strerror}; check that its directory exists "
                              "and is writable") from exc


def write_bscan_png(path: str | Path, bscan: BScan) -> None:
    """The B-scan as a grey image: along-track distance (m) across, time after transmit (ns) down."""
    along = bscan.along_track_m()
    n_samples = bscan.data.shape[1]
    t0 = bscan.t0_ns if math.isfinite(bscan.t0_ns) else 0.0
    t_range = (-t0, (n_samples - 1) * bscan.dt_ns - t0)
    order = np.argsort(along, kind="stable")
    picture = _grey(np.asarray(bscan.data)[order].T, symmetric=True)
    title = f"B-scan: {bscan.data.shape[0]} traces x {n_samples} samples"
    canvas, _ = _framed(picture, (float(along.min()), float(along.max())), t_range, "x (m)", "t (ns)", title)
    _write(path, canvas)


def _outline(canvas: NDArray[np.uint8], mask: NDArray[np.bool_], mapping: tuple[float, float, float, float],
             x_m: NDArray[np.float64], z_m: NDArray[np.float64], colour: tuple[int, int, int]) -> None:
    """Draw the outline of a (nz, nx) mask on the canvas."""
    contours, _ = cv2.findContours(np.asarray(mask, np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    sx, ox, sz, oz = mapping
    for contour in contours:
        cols, rows = contour[:, 0, 0], contour[:, 0, 1]
        pts = np.stack([sx * x_m[cols] + ox, sz * z_m[rows] + oz], axis=1).round().astype(np.int32)
        cv2.polylines(canvas, [pts.reshape(-1, 1, 2)], True, colour, 1)


def write_cross_section_png(
    path: str | Path, section: CrossSection, truth_mask: NDArray[np.bool_] | None = None
) -> None:
    """The migrated image's envelope, mask outline (green), truth outline (red), pipes (yellow), rebars (magenta)."""
    x, z = section.x_m, section.z_m
    picture = _grey(envelope(section.image), symmetric=False)
    kind = "estimated" if section.velocity_estimated else "given"
    title = (f"v = {section.velocity_m_per_ns:.4f} m/ns ({kind}), {len(section.detections)} pipes"
             + (f", {len(section.rebars)} rebars" if section.rebars else ""))
    canvas, mapping = _framed(picture, (float(x[0]), float(x[-1])), (float(z[0]), float(z[-1])),
                              "x (m)", "depth (m)", title)
    if truth_mask is not None:
        _outline(canvas, truth_mask, mapping, x, z, _RED)
    _outline(canvas, section.mask, mapping, x, z, _GREEN)
    sx, ox, sz, oz = mapping
    for d in section.detections:
        px, pz = round(sx * d.x_m + ox), round(sz * d.depth_m + oz)
        cv2.drawMarker(canvas, (px, pz), _YELLOW, cv2.MARKER_CROSS, 10, 1)
        label = f"{d.depth_m:.2f} m, D {d.radius_m * 200:.1f} cm"
        cv2.putText(canvas, label, (px + 6, pz - 6), _FONT, 0.4, _YELLOW, 1)
    for r in section.rebars:
        cv2.circle(canvas, (round(sx * r.x_m + ox), round(sz * r.depth_m + oz)), 4, _MAGENTA, 1)
    _write(path, canvas)
