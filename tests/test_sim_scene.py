"""Scene files: the built-in scenes meet their briefs; bad files are rejected naming the key path."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from gprbot.errors import ConfigError
from gprbot.sim.scene import Pipe, Rebar, Scene, Slab, builtin_scene_names, load_scene, parse_scene

BUILTINS = ("paper_slab", "oblique", "bend_tee", "cluttered_rebar")


def _crossing_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between a segment and the survey lines (x axis), 0–90°."""
    d = b - a
    return math.degrees(math.atan2(abs(d[1]), abs(d[0])))


def _minimal() -> dict[str, Any]:
    return {
        "name": "t",
        "slab": {
            "size_m": [2.4, 1.2],
            "origin_m": [-0.2, -0.1],
            "thickness_m": 0.45,
            "eps_r": 6.0,
            "loss_db_per_m": 10,
        },
        "pipes": [
            {
                "name": f"p{i}",
                "points": [[0.5 + 0.3 * i, -0.1, 0.15], [0.5 + 0.3 * i, 1.1, 0.15]],
                "radius_m": 0.03,
                "fill": "metal",
            }
            for i in range(3)
        ],
    }


@pytest.mark.parametrize("name", BUILTINS)
def test_builtin_scene_loads_and_fits_the_default_survey(name: str) -> None:
    assert name in builtin_scene_names()
    scene = load_scene(name)
    assert scene.name == name and scene.description
    assert scene.slab.size_m == (2.4, 1.2) and scene.slab.origin_m == (-0.2, -0.1)
    assert 0.4 <= scene.slab.thickness_m <= 0.5 and 5.0 <= scene.slab.eps_r <= 8.0
    for pipe in scene.pipes:
        assert np.all((pipe.points[:, 0] >= 0.2) & (pipe.points[:, 0] <= 1.8)), pipe.name
        assert np.all(-pipe.points[:, 2] - pipe.radius_m > 0.0), pipe.name
        assert np.all(-pipe.points[:, 2] + pipe.radius_m < scene.slab.thickness_m), pipe.name
        for a, b in pipe.segments():
            assert _crossing_angle_deg(a, b) >= 45.0, pipe.name
    # Every survey line y = 0.0 … 0.9 crosses every pipe that does not start on another pipe's axis.
    mains = [p for p in scene.pipes if not any(_on_axis(p.points[0], q) for q in scene.pipes if q is not p)]
    for pipe in mains:
        assert pipe.points[:, 1].min() <= -0.1 + 1e-9 and pipe.points[:, 1].max() >= 1.0, pipe.name


def _on_axis(point: np.ndarray, pipe: Pipe) -> bool:
    for a, b in pipe.segments():
        ab = b - a
        s = np.clip((point - a) @ ab / (ab @ ab), 0.0, 1.0)
        if np.linalg.norm(point - (a + s * ab)) < 1e-6:
            return True
    return False


def test_paper_slab_has_the_papers_layout() -> None:
    scene = load_scene("paper_slab")
    assert 3 <= len(scene.pipes) <= 5
    assert {p.fill for p in scene.pipes} == {"metal", "pvc-air", "pvc-water"}
    xs = sorted(float(p.points[0, 0]) for p in scene.pipes)
    assert min(np.diff(xs)) >= 0.25
    for pipe in scene.pipes:
        assert np.allclose(pipe.points[:, 0], pipe.points[0, 0])  # runs along y
        assert 0.015 <= pipe.radius_m <= 0.06 and np.all((-pipe.points[:, 2] >= 0.1) & (-pipe.points[:, 2] <= 0.3))


def test_oblique_and_bend_tee_geometry() -> None:
    angles = [_crossing_angle_deg(*p.segments()[0]) for p in load_scene("oblique").pipes]
    assert 2 <= len(angles) <= 3 and all(45.0 <= a <= 70.0 for a in angles)
    scene = load_scene("bend_tee")
    elbows = [p for p in scene.pipes if len(p.points) >= 3]
    assert len(elbows) == 1
    d0, d1 = (b - a for a, b in elbows[0].segments()[:2])
    turn = math.degrees(math.acos(d0 @ d1 / np.linalg.norm(d0) / np.linalg.norm(d1)))
    assert 30.0 <= turn <= 45.0
    branches = [p for p in scene.pipes if any(_on_axis(p.points[0], q) for q in scene.pipes if q is not p)]
    assert len(branches) == 1


def test_cluttered_rebar_mesh_lies_above_the_pipes_and_inside_the_slab() -> None:
    scene = load_scene("cluttered_rebar")
    assert scene.rebar is not None and scene.clutter is not None
    assert scene.rebar.directions == "xy" and 0.15 <= scene.rebar.spacing_m <= 0.2
    bars = scene.rebar_bars()
    # 2.4 m / 0.2 m = 12 bars along y, 1.2 m / 0.2 m = 6 bars along x
    assert sum(b.name.startswith("rebar_y") for b in bars) == 12
    assert sum(b.name.startswith("rebar_x") for b in bars) == 6
    mesh_bottom = max(float(-b.points[:, 2].max() + b.radius_m) for b in bars)
    assert mesh_bottom == pytest.approx(0.05 + 2 * 0.012)
    for bar in bars:
        assert bar.fill == "metal" and all(scene.slab.contains_xy(*p[:2]) for p in bar.points)
    for pipe in scene.pipes:
        assert float(-pipe.points[:, 2].max()) - pipe.radius_m > mesh_bottom


def test_rebar_bars_positions_and_layers() -> None:
    slab = Slab((1.0, 0.6), (0.0, 0.0), 0.3, 6.0, 10.0)
    scene = Scene("r", "", slab, (), Rebar(0.2, 0.04, 0.01, "xy"), None)
    bars = scene.rebar_bars()
    ys = [b for b in bars if b.name.startswith("rebar_y")]
    xs = [b for b in bars if b.name.startswith("rebar_x")]
    assert [float(b.points[0, 0]) for b in ys] == pytest.approx([0.1, 0.3, 0.5, 0.7, 0.9])
    assert [float(b.points[0, 1]) for b in xs] == pytest.approx([0.1, 0.3, 0.5])
    assert ys[0].points[:, 1].tolist() == [0.0, 0.6] and xs[0].points[:, 0].tolist() == [0.0, 1.0]
    assert float(ys[0].points[0, 2]) == pytest.approx(-0.045) and float(xs[0].points[0, 2]) == pytest.approx(-0.055)


def test_depth_becomes_negative_z_and_pipes_compare_by_value() -> None:
    scene = parse_scene(_minimal(), "t.yaml")
    assert scene.pipes[0].points.tolist() == [[0.5, -0.1, -0.15], [0.5, 1.1, -0.15]]
    assert scene == parse_scene(_minimal(), "t.yaml") and hash(scene.pipes[0]) == hash(
        parse_scene(_minimal(), "t.yaml").pipes[0]
    )
    with pytest.raises(ValueError):
        scene.pipes[0].points[0, 0] = 1.0


def _set(data: dict[str, Any], path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    out = copy.deepcopy(data)
    node: Any = out
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return out


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (("pipez",), [], r"^t\.yaml: pipez: unknown key"),
        (("pipes", 2, "radius_m"), -0.01, r"^t\.yaml: pipes\[2\]\.radius_m: expected a positive number"),
        (("pipes", 1, "radius_m"), "wide", r"pipes\[1\]\.radius_m: expected a positive number, got 'wide'"),
        (("pipes", 0, "colour"), "red", r"pipes\[0\]\.colour: unknown key"),
        (("pipes", 0, "fill"), "copper", r"pipes\[0\]\.fill: expected one of metal, pvc-air, pvc-water"),
        (("pipes", 0, "points"), [[0.5, 0.0, 0.1]], r"pipes\[0\]\.points: expected a list of at least 2"),
        (("pipes", 1, "points", 1), [0.8, 1.1], r"pipes\[1\]\.points\[1\]: expected a list of 3 numbers"),
        (("pipes", 1, "points", 1), [0.8, 1.1, 0.02], r"pipes\[1\]\.points\[1\]: the pipe rises above the surface"),
        (("pipes", 2, "points", 0), [1.1, -0.1, 0.44], r"pipes\[2\]\.points\[0\]: the pipe reaches below the slab"),
        (("pipes", 0, "points", 1), [3.0, 0.5, 0.2], r"pipes\[0\]\.points\[1\]: .* outside the slab"),
        (("pipes", 1, "name"), "p0", r"pipes\[1\]\.name: 'p0' is used twice"),
        (("slab", "eps_r"), "six", r"slab\.eps_r: expected a positive number"),
        (("slab", "size_m"), [2.4], r"slab\.size_m: expected a list of 2 numbers"),
        (("rebar",), {"spacing_m": 0.2, "cover_m": 0.05, "diameter_m": 0.01, "directions": "z"}, r"rebar\.directions"),
        (("rebar",), {"spacing_m": 0.2, "cover_m": 0.05}, r"rebar\.diameter_m: missing"),
        (
            ("clutter",),
            {"count": 1.5, "max_radius_m": 0.01, "depth_range_m": [0.0, 0.3], "seed": 1},
            r"clutter\.count: expected an integer",
        ),
        (
            ("clutter",),
            {"count": 5, "max_radius_m": 0.01, "depth_range_m": [0.0, 0.9], "seed": 1},
            r"clutter\.depth_range_m",
        ),
    ],
)
def test_bad_scene_names_the_key_path(path: tuple[Any, ...], value: Any, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_scene(_set(_minimal(), path, value), "t.yaml")


def test_missing_slab_and_bad_files(tmp_path: Path) -> None:
    data = _minimal()
    del data["slab"]
    with pytest.raises(ConfigError, match=r"slab: missing"):
        parse_scene(data, "t.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(_set(_minimal(), ("pipes", 2, "radius_m"), 0)))
    with pytest.raises(ConfigError, match=r"bad\.yaml: pipes\[2\]\.radius_m: expected a positive number"):
        load_scene(str(bad))
    bad.write_text("slab: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_scene(str(bad))
    with pytest.raises(ConfigError, match="paper_slab"):
        load_scene("no_such_scene")


def test_a_scene_file_round_trips(tmp_path: Path) -> None:
    path = tmp_path / "mine.yaml"
    data = _minimal()
    del data["name"]
    path.write_text(yaml.safe_dump(data))
    scene = load_scene(str(path))
    assert scene.name == "mine" and len(scene.pipes) == 3 and scene.rebar is None


def test_what_lies_under_the_slab_is_soil_unless_the_scene_says_air() -> None:
    assert parse_scene(_minimal(), "t.yaml").slab.below_eps_r == 15.0
    suspended = _minimal()
    suspended["slab"]["below_eps_r"] = 1.0
    assert parse_scene(suspended, "t.yaml").slab.below_eps_r == 1.0
    suspended["slab"]["below_eps_r"] = 0.0
    with pytest.raises(ConfigError, match="below_eps_r"):
        parse_scene(suspended, "t.yaml")
