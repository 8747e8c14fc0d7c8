"""pipes.dxf for CAD (ezdxf, AutoCAD 2010 format, metres): pipe axes, labels, rebars, survey lines.

Layers: PIPES (one 3D polyline per pipe axis, with cover/diameter/confidence as XDATA of the GPRBOT
application), PIPE_LABELS (a text per pipe), REBARS (a point per bar at its depth), SURVEY_LINES.
Coordinates are the site frame, or the configured projected CRS (easting, northing, height).
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping, Sequence
from typing import Any

import ezdxf
import numpy as np
from ezdxf import colors as dxf_colors
from numpy.typing import NDArray

from gprbot.atomic_files import write_bytes_atomic
from gprbot.exports.georef import Georeference
from gprbot.infer.completion import PipeModel, pipe_colors

APP_ID = "GPRBOT"
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
        top = points[-1]
        label = f"P{index} Ø{pipe.diameter_m * 1000:.0f} mm cover {pipe.depth_of_cover_m:.2f} m"
        msp.add_text(label, height=0.04, dxfattribs={"layer": "PIPE_LABELS"}).set_placement(
            (float(top[0]), float(top[1]), 0.0 if georef is None or not georef.has_projected else float(top[2])))
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
