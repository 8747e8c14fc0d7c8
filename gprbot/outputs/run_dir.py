"""Write a survey's results into a run directory: PLYs, pipes.json, exports (DXF, GeoJSON, CSV), PNGs, summary.json."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from gprbot.config import GeoreferenceConfig, build_dataclass
from gprbot.gpr.bscan import BScan
from gprbot.gpr.formats.export import export_survey_lines
from gprbot.gpr.render import write_bscan_png, write_cross_section_png
from gprbot.outputs.depth_slices import depth_bands, depth_slices, render_depth_slices
from gprbot.outputs.dxf import write_dxf
from gprbot.outputs.geojson import write_geojson
from gprbot.outputs.georef import Georeference
from gprbot.outputs.pipes_json import write_json_atomic, write_pipes_json
from gprbot.outputs.ply import write_ply
from gprbot.outputs.render3d import render_3d
from gprbot.outputs.tables import (
    DETECTION_COLUMNS,
    PIPE_COLUMNS,
    detection_rows,
    header_of,
    pipe_rows,
    write_csv,
)
from gprbot.outputs.topdown import render_topdown
from gprbot.reconstruct.completion import pipe_colors
from gprbot.reconstruct.survey_result import SurveyResult

SPARSE_PLY = "sparse.ply"
DENSE_PLY = "dense.ply"
PIPES_JSON = "pipes.json"
SUMMARY_JSON = "summary.json"
REBARS_JSON = "rebars.json"
PIPES_DXF = "pipes.dxf"
PIPES_GEOJSON = "pipes.geojson"
PIPES_CSV = "pipes.csv"
DETECTIONS_CSV = "detections.csv"
DEPTH_SLICES_PNG = "depth_slices.png"
RENDER_3D_PNG = "render3d.png"


def georeference_of(meta: Mapping[str, Any]) -> Georeference | None:
    """The georeference in the run's resolved config (meta["config"]), if it has one."""
    section = (meta.get("config") or {}).get("georeference")
    return Georeference(build_dataclass(GeoreferenceConfig, section, "georeference")) if section else None


def velocity_note(result: SurveyResult) -> str:
    """Where the survey's velocity came from, in words."""
    if result.velocity_method:
        return result.velocity_method
    return "estimated from all lines' hyperbolas" if result.velocity_estimated else "from the configured eps_r"


def write_exports(out_dir: Path, result: SurveyResult, meta: Mapping[str, Any]) -> list[Path]:
    """pipes.dxf, pipes.csv, detections.csv, and pipes.geojson when the site is georeferenced."""
    georef = georeference_of(meta)
    pipes = result.reconstruction.pipes
    rebars = rebars_record(result)["rebars"]
    lines = {lr.line: lr.bscan.positions[:, :2] for lr in result.lines}
    write_dxf(out_dir / PIPES_DXF, pipes, rebars, lines, georef, meta)
    rows = pipe_rows(pipes, georef)
    write_csv(out_dir / PIPES_CSV, rows, header_of(rows, PIPE_COLUMNS))
    rows = detection_rows(result, georef)
    write_csv(out_dir / DETECTIONS_CSV, rows, header_of(rows, DETECTION_COLUMNS))
    written = [out_dir / PIPES_DXF, out_dir / PIPES_CSV, out_dir / DETECTIONS_CSV]
    if georef is not None and georef.has_wgs84:
        write_geojson(out_dir / PIPES_GEOJSON, pipes, rebars, lines, georef, meta)
        written.append(out_dir / PIPES_GEOJSON)
    return written


def rebars_record(result: SurveyResult) -> dict[str, Any]:
    """Every line's reinforcement bars in the site frame (the mesh, which pipes.json does not hold)."""
    bars = []
    for lr in result.lines:
        for bar in lr.section.rebars:
            x, y, _ = (float(c) for c in lr.bscan.position_at(bar.x_m))
            bars.append({"line": lr.line, "along_m": round(bar.x_m, 4), "x_m": round(x, 4), "y_m": round(y, 4),
                         "depth_m": round(bar.depth_m, 4), "confidence": round(bar.score, 3)})
    return {"frame": "site (x forward, y left, z up), metres; depth below the surface to the bar's centre",
            "method": "interpretation chain: evenly spaced reflectors at one cover on a line", "rebars": bars}


def write_survey_outputs(
    out_dir: Path,
    result: SurveyResult,
    meta: dict[str, Any],
    extent_xy: tuple[float, float, float, float],
    truth_axes: list[np.ndarray] | None = None,
    truth_masks: dict[int, np.ndarray] | None = None,
    raw_lines: Mapping[int, BScan] | None = None,
) -> list[Path]:
    """Write every result file of a survey into out_dir (created if needed); returns the paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    recon = result.reconstruction
    comments = [f"gprbot run {meta.get('run', '')}", "frame: site (x forward, y left, z up), metres"]

    write_ply(out_dir / SPARSE_PLY, result.sparse, comments=[*comments, "sparse registered cloud"])
    written.append(out_dir / SPARSE_PLY)
    colors = pipe_colors(max(len(recon.pipes), 1))[recon.labels] if len(recon.dense) else None
    write_ply(out_dir / DENSE_PLY, recon.dense, colors, comments=[*comments, "dense completed cloud"])
    written.append(out_dir / DENSE_PLY)
    write_pipes_json(out_dir / PIPES_JSON, recon, meta)
    written.append(out_dir / PIPES_JSON)
    write_json_atomic(out_dir / REBARS_JSON, rebars_record(result))
    written.append(out_dir / REBARS_JSON)

    written += write_exports(out_dir, result, meta)

    note = velocity_note(result)
    for lr in result.lines:
        bscan_png = out_dir / f"bscan_line{lr.line:02d}.png"
        write_bscan_png(bscan_png, lr.bscan, result.velocity_m_per_ns, note, title=f"Line {lr.line} B-scan")
        section_png = out_dir / f"section_line{lr.line:02d}.png"
        truth = truth_masks.get(lr.line) if truth_masks else None
        write_cross_section_png(section_png, lr.section, truth, lr.bscan, note, title=f"Line {lr.line}")
        written += [bscan_png, section_png]

    if raw_lines:  # the recorded traces, for GPR programs: line-NN.DZT, .DT1/.HD, -poses.csv
        written += export_survey_lines(out_dir, raw_lines, meta.get("config", {}).get("gpr"))
    survey_lines = [lr.bscan.positions[:, :2] for lr in result.lines]
    map_png = out_dir / "map.png"
    render_topdown(map_png, recon, extent_xy, truth_axes or [], survey_lines)
    written.append(map_png)
    if result.lines:
        depth_max = max(float(lr.section.z_m[-1]) for lr in result.lines)
        slices = depth_slices(result, depth_bands(depth_max), extent_xy)
        render_depth_slices(out_dir / DEPTH_SLICES_PNG, result, slices, note)
        written.append(out_dir / DEPTH_SLICES_PNG)
    render_3d(out_dir / RENDER_3D_PNG, recon, survey_lines)
    written.append(out_dir / RENDER_3D_PNG)

    summary = {
        **meta,
        "velocity_m_per_ns": result.velocity_m_per_ns,
        "velocity_estimated": result.velocity_estimated,
        "velocity_method": velocity_note(result),
        "lines": len(result.lines),
        "skipped_lines": {str(k): why for k, why in result.skipped_lines.items()},
        "pipes_found": len(recon.pipes),
        "rebars_found": sum(len(lr.section.rebars) for lr in result.lines),
        "sparse_points": len(result.sparse),
        "dense_points": len(recon.dense),
        "timings_s": result.timings_s,
        "files": [*sorted(p.name for p in written), SUMMARY_JSON],
    }
    write_json_atomic(out_dir / SUMMARY_JSON, summary)
    written.append(out_dir / SUMMARY_JSON)
    return written
