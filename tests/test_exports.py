"""Exports read back by independent readers: ezdxf (DXF), an RFC 7946 schema (GeoJSON), csv, mcap, plyfile."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import ezdxf
import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader
from plyfile import PlyData

from gprbot.apps.replay import record_simulated_survey, replay_run
from gprbot.cli import main
from gprbot.config import GeoreferenceConfig, load_config
from gprbot.errors import ConfigError
from gprbot.exports.mcap_log import export_mcap
from gprbot.messages import Pose, Trace
from gprbot.outputs.dxf import write_dxf
from gprbot.outputs.georef import Georeference
from gprbot.reconstruct.completion import PipeModel
from gprbot.runlog_reader import RunLogReader
from gprbot.sim.scene import load_scene

# The origin of a made-up site (a car park in Zurich); heading 30°: site +x points north-north-east.
GEO = GeoreferenceConfig(heading_deg=30.0, origin_lat_deg=47.3769, origin_lon_deg=8.5417, origin_height_m=450.0,
                         crs="EPSG:2056", origin_easting_m=2683000.0, origin_northing_m=1248000.0)

_POSITION = {"type": "array", "minItems": 2, "maxItems": 3, "items": {"type": "number"},
             "prefixItems": [{"minimum": -180, "maximum": 180}, {"minimum": -90, "maximum": 90}]}
RFC7946 = {  # the parts of RFC 7946 our file uses: FeatureCollection of Features with Point/LineString
    "type": "object", "required": ["type", "features"],
    "properties": {
        "type": {"const": "FeatureCollection"},
        "features": {"type": "array", "items": {
            "type": "object", "required": ["type", "geometry", "properties"],
            "properties": {
                "type": {"const": "Feature"},
                "id": {"type": ["string", "number"]},
                "properties": {"type": ["object", "null"]},
                "geometry": {"oneOf": [
                    {"type": "object", "required": ["type", "coordinates"],
                     "properties": {"type": {"const": "Point"}, "coordinates": _POSITION}},
                    {"type": "object", "required": ["type", "coordinates"],
                     "properties": {"type": {"const": "LineString"},
                                    "coordinates": {"type": "array", "minItems": 2, "items": _POSITION}}},
                ]},
            }}},
    },
    "not": {"required": ["crs"]},  # RFC 7946 §4: no crs member; WGS84 only
}


def _local_en_m(lon0: float, lat0: float, lon: float, lat: float) -> tuple[float, float]:
    """East and north (m) of a nearby point from the ellipsoid's radii of curvature (an independent method:
    no ECEF; exact to well below a millimetre over 100 m)."""
    a, e2 = 6378137.0, 0.00669437999014
    s = math.sin(math.radians(lat0)) ** 2
    meridian = a * (1 - e2) / (1 - e2 * s) ** 1.5
    prime_vertical = a / math.sqrt(1 - e2 * s)
    east = math.radians(lon - lon0) * prime_vertical * math.cos(math.radians(lat0))
    return east, math.radians(lat - lat0) * meridian


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A 3-line survey recorded as a run log, replayed with a georeferenced config into out/."""
    base = load_config()
    cfg = dataclasses.replace(base, survey=dataclasses.replace(base.survey, lines=3, length_m=1.0), georeference=GEO,
                              sim=dataclasses.replace(base.sim, poses="noise"))  # no VO: seconds, not a minute
    root = tmp_path_factory.mktemp("exports")
    run_dir = root / "run-0001"
    record_simulated_survey(cfg, load_scene("paper_slab"), run_dir, 1.7e9)
    out = root / "out"
    result = replay_run(run_dir, out, cfg)
    return {"cfg": cfg, "run_dir": run_dir, "out": out, "result": result}


def test_georeference_is_exact_against_an_independent_great_circle() -> None:
    geo = Georeference(GEO)
    site = np.array([[100.0, 0.0, -1.0], [0.0, 50.0, 0.0]])
    (lon0, lat0, h0), = geo.lon_lat_height(np.zeros((1, 3)))
    assert (lon0, lat0, h0) == pytest.approx((GEO.origin_lon_deg, GEO.origin_lat_deg, 450.0), abs=1e-9)
    (lon1, lat1, h1), (lon2, lat2, _) = geo.lon_lat_height(site)
    heading = math.radians(30.0)
    # +x runs along the heading (30° east of north), +y 90° to its left (300°)
    assert _local_en_m(lon0, lat0, lon1, lat1) == pytest.approx((100 * math.sin(heading), 100 * math.cos(heading)),
                                                                abs=0.02)
    assert _local_en_m(lon0, lat0, lon2, lat2) == pytest.approx((-50 * math.cos(heading), 50 * math.sin(heading)),
                                                                abs=0.01)
    assert h1 == pytest.approx(449.0, abs=2e-3)  # 1 m down; the earth curves away by < 1 mm over 100 m
    east, north, _ = geo.projected(site[:1])[0]
    assert (east - 2683000.0, north - 1248000.0) == pytest.approx((50.0, 86.6025), abs=1e-3)


def test_a_half_georeference_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="origin_lon_deg"):
        GeoreferenceConfig(origin_lat_deg=47.0)
    with pytest.raises(ConfigError, match="origin_easting_m"):
        GeoreferenceConfig(crs="EPSG:2056")
    with pytest.raises(ConfigError, match="origin_lat_deg"):
        GeoreferenceConfig(origin_lat_deg=91.0, origin_lon_deg=0.0)


def test_geojson_is_rfc7946_and_places_the_pipes(run: dict[str, Any]) -> None:
    doc = json.loads((run["out"] / "pipes.geojson").read_text())
    jsonschema.validate(doc, RFC7946)
    pipes = [f for f in doc["features"] if f["properties"]["kind"] == "pipe"]
    found = run["result"].reconstruction.pipes
    assert len(pipes) == len(found) >= 2  # a 1 m survey crosses two of paper_slab's pipes
    geo = Georeference(GEO)
    (lon0, lat0, _), = geo.lon_lat_height(np.zeros((1, 3)))
    for feature, pipe in zip(pipes, found, strict=True):
        assert feature["properties"]["diameter_m"] == pytest.approx(pipe.diameter_m, abs=1e-4)
        assert feature["properties"]["depth_of_cover_m"] == pytest.approx(pipe.depth_of_cover_m, abs=1e-4)
        lon, lat, height = feature["geometry"]["coordinates"][0]
        start = pipe.axis[0]
        heading = math.radians(30.0)
        east = start[0] * math.sin(heading) - start[1] * math.cos(heading)
        north = start[0] * math.cos(heading) + start[1] * math.sin(heading)
        assert _local_en_m(lon0, lat0, lon, lat) == pytest.approx((east, north), abs=2e-3)  # 1e-8° rounding
        assert height == pytest.approx(450.0 + start[2], abs=1e-3)
    lines = [f for f in doc["features"] if f["properties"]["kind"] == "survey_line"]
    assert len(lines) == 3


def test_dxf_reads_back_with_ezdxf(run: dict[str, Any]) -> None:
    doc = ezdxf.readfile(run["out"] / "pipes.dxf")  # type: ignore[attr-defined]
    assert doc.units == ezdxf.units.M
    assert {"PIPES", "PIPE_LABELS", "REBARS", "SURVEY_LINES"} <= {layer.dxf.name for layer in doc.layers}
    msp = doc.modelspace()
    polylines = list(msp.query("POLYLINE[layer=='PIPES']"))
    found = run["result"].reconstruction.pipes
    assert len(polylines) == len(found)
    geo = Georeference(GEO)
    for polyline, pipe in zip(polylines, found, strict=True):
        assert polyline.is_3d_polyline
        vertices = np.array([v.dxf.location for v in polyline.vertices])
        np.testing.assert_allclose(vertices, geo.projected(pipe.axis), atol=1e-6)  # in the configured CRS
        numbers = [value for code, value in polyline.get_xdata("GPRBOT") if code == 1040]
        assert numbers == pytest.approx([pipe.depth_of_cover_m, pipe.diameter_m, pipe.confidence])
    assert len(msp.query("TEXT[layer=='PIPE_LABELS']")) == len(found)
    assert len(msp.query("LINE[layer=='SURVEY_LINES']")) == 3


def test_dxf_in_the_site_frame_holds_rebars_as_points(tmp_path: Path) -> None:
    pipe = PipeModel(np.array([[0.5, 0.0, -0.2], [0.5, 1.0, -0.2]]), 0.05, 0.15, 0.1, 0.9, 5)
    bars = [{"line": 0, "x_m": 0.1 * k, "y_m": 0.0, "depth_m": 0.05, "confidence": 0.8} for k in range(4)]
    write_dxf(tmp_path / "p.dxf", [pipe], bars, {0: np.array([[0.0, 0.0], [1.0, 0.0]])}, None, {"run": "r"})
    msp = ezdxf.readfile(tmp_path / "p.dxf").modelspace()  # type: ignore[attr-defined]
    points = np.array([p.dxf.location for p in msp.query("POINT[layer=='REBARS']")])
    np.testing.assert_allclose(points, [[0.1 * k, 0.0, -0.05] for k in range(4)], atol=1e-9)
    (polyline,) = msp.query("POLYLINE[layer=='PIPES']")
    np.testing.assert_allclose([v.dxf.location for v in polyline.vertices], pipe.axis)


def test_csv_tables_match_the_pipes_and_detections(run: dict[str, Any]) -> None:
    with (run["out"] / "pipes.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    found = run["result"].reconstruction.pipes
    assert len(rows) == len(found)
    for row, pipe in zip(rows, found, strict=True):
        assert float(row["diameter_m"]) == pytest.approx(pipe.diameter_m, abs=1e-4)
        assert float(row["start_x_m"]) == pytest.approx(pipe.axis[0, 0], abs=1e-4)
        assert {"start_lon_deg", "start_lat_deg", "start_easting_m", "end_northing_m"} <= row.keys()
    with (run["out"] / "detections.csv").open(newline="") as f:
        detections = list(csv.DictReader(f))
    expected = sum(len(lr.section.detections) + len(lr.section.rebars) for lr in run["result"].lines)
    assert len(detections) == expected > 0
    assert {d["kind"] for d in detections} <= {"pipe", "rebar"} and {d["line"] for d in detections} == {"0", "1", "2"}


def test_ply_reads_back_with_plyfile(run: dict[str, Any]) -> None:
    dense = PlyData.read(str(run["out"] / "dense.ply"))["vertex"]
    assert len(dense) == len(run["result"].reconstruction.dense)
    np.testing.assert_allclose(np.column_stack([dense["x"], dense["y"], dense["z"]]),
                               run["result"].reconstruction.dense, atol=1e-6)


def test_every_section_says_how_the_survey_velocity_was_found(run: dict[str, Any]) -> None:
    result = run["result"]
    assert result.velocity_estimated  # no eps_r configured: estimated from all lines' hyperbolas
    # before: each line was interpreted AT that velocity and its section said "given"
    assert all(lr.section.velocity_estimated for lr in result.lines)


def test_pictures_are_written(run: dict[str, Any]) -> None:
    for name in ("depth_slices.png", "render3d.png", "bscan_line01.png", "section_line01.png", "map.png"):
        assert (run["out"] / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
    summary = json.loads((run["out"] / "summary.json").read_text())
    assert {"pipes.dxf", "pipes.geojson", "pipes.csv", "detections.csv", "depth_slices.png"} <= set(summary["files"])


def test_mcap_export_reads_back_with_the_mcap_reader(run: dict[str, Any], tmp_path: Path) -> None:
    reader = RunLogReader(run["run_dir"])
    logged = [r.message for r in reader]
    poses = [m for m in logged if isinstance(m, Pose)]
    traces = [m for m in logged if isinstance(m, Trace)]
    done = export_mcap(run["run_dir"], tmp_path / "run.mcap")
    with (tmp_path / "run.mcap").open("rb") as f:
        mcap = make_reader(f)
        summary = mcap.get_summary()
        assert summary is not None
        topics = {c.topic: c for c in summary.channels.values()}
        assert {"/pose", "/gpr/trace", "/survey/events"} <= topics.keys()
        assert summary.schemas[topics["/pose"].schema_id].name == "foxglove.PoseInFrame"
        decoded: dict[str, list[Any]] = {}
        times = []
        for _, channel, message in mcap.iter_messages():
            decoded.setdefault(channel.topic, []).append(json.loads(message.data))
            times.append(message.log_time)
        metadata = {m.name: m.metadata for m in mcap.iter_metadata()}
    assert len(decoded["/pose"]) == len(poses) and len(decoded["/gpr/trace"]) == len(traces)
    assert done.messages["/pose"] == len(poses)
    first = decoded["/pose"][0]["pose"]["position"]
    assert (first["x"], first["y"], first["z"]) == pytest.approx(tuple(poses[0].position))
    np.testing.assert_allclose(decoded["/gpr/trace"][5]["samples"], traces[5].samples, rtol=1e-6)
    assert times == sorted(times) and times[0] == pytest.approx(1.7e18, rel=1e-9)  # the run's wall time
    assert json.loads(metadata["gprbot.header"]["json"])["created"] == 1.7e9


def test_export_mcap_command(run: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x.mcap"
    assert main(["--quiet", "export-mcap", str(run["run_dir"]), "--out", str(out), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["mcap"] == str(out) and printed["messages"]["/pose"] > 0 and not printed["run_log"]["torn"]
    assert main(["export-mcap", str(tmp_path / "missing")]) == 1
    assert capsys.readouterr().err.startswith("gprbot: error:")
