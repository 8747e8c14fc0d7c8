"""pipes.geojson (RFC 7946): pipes as LineStrings, rebars as Points, survey lines; WGS84 lon/lat/height.

RFC 7946 has no other CRS, so the file is written only when the config places the site on the earth
(georeference.origin_lat_deg / origin_lon_deg). Heights are the WGS84 ellipsoidal heights of the pipe
axis (origin height + z); each feature's properties also carry the site-frame numbers.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.geometry import polyline_length
from gprbot.outputs.georef import Georeference
from gprbot.outputs.pipes_json import write_json_atomic
from gprbot.reconstruct.completion import PipeModel, pipe_colors

_DEGREE_DECIMALS = 8  # 1e-8° ≈ 1 mm
_HEIGHT_DECIMALS = 4


def _coordinates(georef: Georeference, site: NDArray[np.float64]) -> list[list[float]]:
    llh = georef.lon_lat_height(site)
    return [[round(float(lon), _DEGREE_DECIMALS), round(float(lat), _DEGREE_DECIMALS),
             round(float(h), _HEIGHT_DECIMALS)] for lon, lat, h in llh]


def geojson_document(pipes: Sequence[PipeModel], rebars: Sequence[Mapping[str, Any]],
                     survey_lines: Mapping[int, NDArray[np.float64]], georef: Georeference,
                     meta: Mapping[str, Any]) -> dict[str, Any]:
    """The FeatureCollection of a run: one feature per pipe, rebar and survey line."""
    features: list[dict[str, Any]] = []
    colours = pipe_colors(max(len(pipes), 1))
    for index, pipe in enumerate(pipes):
        features.append({
            "type": "Feature", "id": f"pipe-{index}",
            "geometry": {"type": "LineString", "coordinates": _coordinates(georef, pipe.axis)},
            "properties": {
                "kind": "pipe", "pipe": index, "depth_of_cover_m": round(pipe.depth_of_cover_m, 4),
                "diameter_m": round(pipe.diameter_m, 4), "confidence": round(pipe.confidence, 3),
                "length_m": round(polyline_length(pipe.axis), 4), "n_slices": pipe.n_slices,
                "colour": "#{:02x}{:02x}{:02x}".format(*(int(c) for c in colours[index])),
                "axis_site_m": np.round(pipe.axis, 4).tolist(),
            },
        })
    for index, bar in enumerate(rebars):
        site = np.array([[bar["x_m"], bar["y_m"], -bar["depth_m"]]])
        features.append({
            "type": "Feature", "id": f"rebar-{index}",
            "geometry": {"type": "Point", "coordinates": _coordinates(georef, site)[0]},
            "properties": {"kind": "rebar", "line": bar["line"], "depth_m": bar["depth_m"],
                           "confidence": bar["confidence"]},
        })
    for line, xy in sorted(survey_lines.items()):
        ends = np.column_stack([np.asarray(xy)[[0, -1], :2], np.zeros(2)])
        features.append({
            "type": "Feature", "id": f"line-{line}",
            "geometry": {"type": "LineString", "coordinates": _coordinates(georef, ends)},
            "properties": {"kind": "survey_line", "line": line},
        })
    c = georef.config
    return {
        "type": "FeatureCollection",
        "name": f"gprbot run {meta.get('run', '')}",
        "gprbot": {"site_frame": "x forward along the survey lines, y left, z up; metres",
                   "origin": {"lat_deg": c.origin_lat_deg, "lon_deg": c.origin_lon_deg, "height_m": c.origin_height_m},
                   "heading_deg": c.heading_deg, "heights": "WGS84 ellipsoidal, metres"},
        "features": features,
    }


def write_geojson(path: str | os.PathLike[str], pipes: Sequence[PipeModel], rebars: Sequence[Mapping[str, Any]],
                  survey_lines: Mapping[int, NDArray[np.float64]], georef: Georeference,
                  meta: Mapping[str, Any]) -> None:
    """Write pipes.geojson atomically."""
    write_json_atomic(path, geojson_document(pipes, rebars, survey_lines, georef, meta))
