"""pipes.dxf for CAD (ezdxf, AutoCAD 2010 format, metres): pipe axes, labels, rebars, survey lines.

Layers: PIPES (one 3D polyline per pipe axis, with cover/diameter/confidence as XDATA of the GPRBOT
application), PIPE_LABELS (a text per pipe), REBARS (a point per bar at its depth), SURVEY_LINES.
Coordinates are the site frame, or the configured projected CRS (easting, northing, height).
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Mapping, Sequence
from typing import Any

import ezdxf
import numpy as np
from ezdxf import colors as dxf_colors
from ezdxf.enums import TextEntityAlignment
from numpy.typing import NDArray

from gprbot.atomic_files import write_bytes_atomic
from gprbot.outputs.georef import Georeference
from gprbot.reconstruct.completion import PipeModel, pipe_colors

APP_ID = "GPRBOT"
LABEL_HEIGHT_M = 0.025  # 2.5 cm text: readable at 1:20, the scale of a slab survey
LAYERS = {"PIPES": 1, "PIPE_LABELS": 7, "REBARS": 6, "SURVEY_LINES": 5}  # ACI colours


def _place(georef: Georeference | None, site: NDArray[np.float64]) -> NDArray[np.float64]:
    """Site points in the drawing's coordinates: the projected CRS when configured, else the site frame."""
    p = np.atleast_2d(np.asarray(site, dtype=np.float64))
    return georef.projected(p) if georef is not None and georef.has_projected else p


def dxf_bytes(pipes: Sequence[PipeModel], rebars: Sequence[Mapping[str, Any]],
              survey_lines: Mapping[int, NDArray[np.float64]], georef: Georeference | None,
              meta: Mapping[str, Any]) -> bytes:
    """The DXF drawing of a run, as bytes (text DXF, UTF-8)."""
    doc = ezdxf.new("R2010", setup=True)  # type: ignore[attr-defined]
    doc.units = ezdxf.units.M
    doc.appids.add(APP_ID)
    for name, colour in LAYERS.items():
        doc.layers.add(name, color=colour)
    crs = georef.config.crs if georef is not None and georef.has_projected else "site frame (x forward, y left, z up)"
    doc.header["$PROJECTNAME"] = f"gprbot run {meta.get('run', '')}"
    msp = doc.modelspace()
    colours = pipe_colors(max(len(pipes), 1))
    for index, pipe in enumerate(pipes):
        points = _place(georef, pipe.axis)
        polyline = msp.add_polyline3d([tuple(map(float, p)) for p in points], dxfattribs={"layer": "PIPES"})
        r, g, b = (int(c) for c in colours[index])
        polyline.dxf.true_color = dxf_colors.rgb2int((r, g, b))
        polyline.set_xdata(APP_ID, [
            (1000, f"pipe {index}"), (1000, f"coordinates: {crs}"),
            (1040, float(pipe.depth_of_cover_m)), (1000, "depth_of_cover_m"),
            (1040, float(pipe.diameter_m)), (1000, "diameter_m"),
            (1040, float(pipe.confidence)), (1000, "confidence"),
        ])
        # the label runs along the pipe from its middle (pipes a few decimetres apart must not share a line);
        # %%c is DXF's diameter sign, which every CAD font draws
        label = f"P{index} %%c{pipe.diameter_m * 1000:.0f} mm, cover {pipe.depth_of_cover_m:.2f} m"
        middle = len(points) // 2
        a, b = points[max(middle - 1, 0)], points[min(middle, len(points) - 1)] if len(points) > 1 else points[0]
        angle = math.degrees(math.atan2(float(b[1] - a[1]), float(b[0] - a[0]))) if len(points) > 1 else 0.0
        angle = angle - 180.0 if angle > 90.0 else angle + 180.0 if angle <= -90.0 else angle  # never upside down
        at = (points[0] + points[-1]) / 2 if len(points) == 2 else points[middle]
        msp.add_text(label, height=LABEL_HEIGHT_M, rotation=angle, dxfattribs={"layer": "PIPE_LABELS"}).set_placement(
            (float(at[0]), float(at[1]), float(at[2])), align=TextEntityAlignment.BOTTOM_CENTER)
    for bar in rebars:
        p = _place(georef, np.array([[bar["x_m"], bar["y_m"], -bar["depth_m"]]]))[0]
        msp.add_point(tuple(map(float, p)), dxfattribs={"layer": "REBARS"})
    for _, xy in sorted(survey_lines.items()):
        ends = _place(georef, np.column_stack([np.asarray(xy)[[0, -1], :2], np.zeros(2)]))
        msp.add_line(tuple(map(float, ends[0])), tuple(map(float, ends[1])), dxfattribs={"layer": "SURVEY_LINES"})
    stream = io.StringIO()
    doc.write(stream)
    return stream.getvalue().encode("utf-8")


def write_dxf(path: str | os.PathLike[str], pipes: Sequence[PipeModel], rebars: Sequence[Mapping[str, Any]],
              survey_lines: Mapping[int, NDArray[np.float64]], georef: Georeference | None,
              meta: Mapping[str, Any]) -> None:
    """Write pipes.dxf atomically."""
    write_bytes_atomic(path, dxf_bytes(pipes, rebars, survey_lines, georef, meta))
