"""pipes.csv and detections.csv: one row per pipe, one per pipe crossing or rebar seen on a line.

Site-frame metres always; WGS84 lon/lat and projected easting/northing columns are added when the
config's georeference gives them. Plain RFC 4180 CSV (comma, header row, '.' decimals) that a
spreadsheet or pandas opens as it is.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from gprbot.atomic_files import write_bytes_atomic
from gprbot.geometry import polyline_length
from gprbot.outputs.georef import Georeference
from gprbot.reconstruct.completion import PipeModel
from gprbot.reconstruct.survey_result import SurveyResult


def _earth_columns(georef: Georeference | None, prefix: str, point: np.ndarray) -> dict[str, float]:
    """lon/lat and easting/northing of one site point, for the columns the georeference allows."""
    row: dict[str, float] = {}
    if georef is None:
        return row
    if georef.has_wgs84:
        lon, lat, _ = georef.lon_lat_height(point[None, :])[0]
        row[f"{prefix}lon_deg"], row[f"{prefix}lat_deg"] = round(float(lon), 8), round(float(lat), 8)
    if georef.has_projected:
        e, n, _ = georef.projected(point[None, :])[0]
        row[f"{prefix}easting_m"], row[f"{prefix}northing_m"] = round(float(e), 4), round(float(n), 4)
    return row


def pipe_rows(pipes: Sequence[PipeModel], georef: Georeference | None) -> list[dict[str, Any]]:
    """One row per pipe: size, cover, confidence, both ends (site, and on the earth when georeferenced)."""
    rows = []
    for index, pipe in enumerate(pipes):
        start, end = pipe.axis[0], pipe.axis[-1]
        row: dict[str, Any] = {
            "pipe": index, "diameter_m": round(pipe.diameter_m, 4), "depth_of_cover_m": round(pipe.depth_of_cover_m, 4),
            "length_m": round(polyline_length(pipe.axis), 4), "confidence": round(pipe.confidence, 3),
            "n_slices": pipe.n_slices, "vertices": len(pipe.axis),
            "start_x_m": round(float(start[0]), 4), "start_y_m": round(float(start[1]), 4),
            "start_z_m": round(float(start[2]), 4),
            "end_x_m": round(float(end[0]), 4), "end_y_m": round(float(end[1]), 4), "end_z_m": round(float(end[2]), 4),
        }
        row |= _earth_columns(georef, "start_", start) | _earth_columns(georef, "end_", end)
        rows.append(row)
    return rows


def detection_rows(result: SurveyResult, georef: Georeference | None) -> list[dict[str, Any]]:
    """One row per pipe crossing and per rebar found on each line (site position of the reflector's centre)."""
    rows = []
    for lr in result.lines:
        for kind, found in (("pipe", lr.section.detections), ("rebar", lr.section.rebars)):
            for d in found:
                x, y, _ = (float(c) for c in lr.bscan.position_at(d.x_m))
                centre = np.array([x, y, -d.depth_m])
                row: dict[str, Any] = {
                    "line": lr.line, "kind": kind, "along_m": round(d.x_m, 4), "x_m": round(x, 4), "y_m": round(y, 4),
                    "centre_depth_m": round(d.depth_m, 4), "diameter_m": round(2 * d.radius_m, 4),
                    "score": round(d.score, 3),
                }
                rows.append(row | _earth_columns(georef, "", centre))
    return rows


def csv_bytes(rows: Sequence[dict[str, Any]], header: Sequence[str]) -> bytes:
    """Rows as CSV (header first; a missing value is empty)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(header), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue().encode("utf-8")


def write_csv(path: str | os.PathLike[str], rows: Sequence[dict[str, Any]], header: Sequence[str]) -> None:
    """Write rows as CSV atomically (the header is given so that an empty table still has its columns)."""
    write_bytes_atomic(path, csv_bytes(rows, header))


def header_of(rows: Sequence[dict[str, Any]], base: Sequence[str]) -> list[str]:
    """The base columns, then any extra (georeferenced) columns the rows have, in first-seen order."""
    extra = [k for row in rows for k in row if k not in base]
    return [*base, *dict.fromkeys(extra)]


PIPE_COLUMNS = ("pipe", "diameter_m", "depth_of_cover_m", "length_m", "confidence", "n_slices", "vertices",
                "start_x_m", "start_y_m", "start_z_m", "end_x_m", "end_y_m", "end_z_m")
DETECTION_COLUMNS = ("line", "kind", "along_m", "x_m", "y_m", "centre_depth_m", "diameter_m", "score")
