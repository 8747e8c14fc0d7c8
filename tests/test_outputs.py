"""Result files: atomic writes, pipes.json and the top-down map."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from gprbot.atomic_files import atomic_open
from gprbot.errors import DataFormatError
from gprbot.outputs.pipes_json import read_pipes_json, write_json_atomic, write_pipes_json
from gprbot.outputs.topdown import MAP_SIDE_PX, MARGIN_PX, render_topdown
from gprbot.reconstruct.completion import PipeModel, Reconstruction, pipe_colors


def reconstruction() -> Reconstruction:
    main = PipeModel(
        axis=np.array([[1.0, -0.05, -0.2], [1.0, 0.95, -0.2]]),
        radius_m=0.05,
        depth_of_cover_m=0.15,
        diameter_m=0.1,
        confidence=0.93,
        n_slices=10,
    )
    branch = PipeModel(
        axis=np.array([[1.0, 0.4, -0.2], [1.3, 0.7, -0.21], [1.3, 0.95, -0.22]]),
        radius_m=0.02,
        depth_of_cover_m=0.18,
        diameter_m=0.04,
        confidence=0.61,
        n_slices=5,
        ends_on=(0, None),
    )
    return Reconstruction(pipes=(main, branch), dense=np.zeros((0, 3)), labels=np.zeros(0, dtype=np.intp))


def test_interrupted_write_leaves_the_old_file_and_no_temp(tmp_path: Path) -> None:
    path = tmp_path / "summary.json"
    path.write_text("old")
    with pytest.raises(RuntimeError), atomic_open(path) as handle:
        handle.write(b"half of the new")
        raise RuntimeError("power cut")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]


def test_json_takes_numpy_values_and_refuses_nan(tmp_path: Path) -> None:
    obj = {"n": np.int64(3), "x": np.float32(0.5), "ok": np.bool_(True), "v": np.arange(3), "p": tmp_path}
    write_json_atomic(tmp_path / "a.json", obj)
    assert json.loads((tmp_path / "a.json").read_text()) == {
        "n": 3,
        "x": 0.5,
        "ok": True,
        "v": [0, 1, 2],
        "p": str(tmp_path),
    }
    with pytest.raises(ValueError):
        write_json_atomic(tmp_path / "b.json", {"x": float("nan")})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]


def test_pipes_json_round_trips(tmp_path: Path) -> None:
    recon = reconstruction()
    write_pipes_json(tmp_path / "pipes.json", recon, {"run": "2024-05-01T10-00-00", "scene": "bend_tee"})
    doc = json.loads((tmp_path / "pipes.json").read_text())
    assert doc["format"] == "gprbot-pipes" and doc["version"] == 1
    assert doc["meta"]["units"] == "m" and "z up" in doc["meta"]["frame"]
    assert doc["meta"]["run"] == "2024-05-01T10-00-00" and doc["meta"]["scene"] == "bend_tee"
    assert len(doc["pipes"]) == 2
    for index, (record, pipe) in enumerate(zip(doc["pipes"], recon.pipes, strict=True)):
        assert record["id"] == index
        np.testing.assert_allclose(record["axis_m"], pipe.axis, atol=1e-6)
        np.testing.assert_allclose(record["endpoints_m"], pipe.axis[[0, -1]], atol=1e-6)
        assert record["depth_of_cover_m"] == pytest.approx(pipe.depth_of_cover_m, abs=1e-6)
        assert record["diameter_m"] == pytest.approx(pipe.diameter_m, abs=1e-6)
        assert record["confidence"] == pytest.approx(pipe.confidence, abs=1e-4)
        assert record["n_slices"] == pipe.n_slices
        assert record["colour"] == "#{:02x}{:02x}{:02x}".format(*pipe_colors(2)[index])
    assert doc["pipes"][1]["ends_on"] == {"start": 0, "end": None}
    assert doc["pipes"][1]["length_m"] == pytest.approx(np.hypot(0.3, 0.3) + 0.25, abs=1e-3)


def test_topdown_map_draws_pipes_truth_and_lines(tmp_path: Path) -> None:
    recon = reconstruction()
    path = tmp_path / "map.png"
    lines = [np.column_stack([np.linspace(0.0, 2.0, 50), np.full(50, y)]) for y in (0.0, 0.5)]
    truth = [np.array([[0.5, 0.0, -0.2], [0.5, 1.0, -0.2]])]
    render_topdown(path, recon, (0.0, 2.0, -0.1, 1.0), truth, lines)
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert image is not None and [p.name for p in tmp_path.iterdir()] == ["map.png"]
    scale = MAP_SIDE_PX / 2.0

    def pixel(x: float, y: float) -> np.ndarray:
        return image[round(MARGIN_PX + (1.0 - y) * scale), round(MARGIN_PX + x * scale)].astype(int)

    main_bgr = pipe_colors(2)[0][::-1].astype(int)
    assert np.abs(pixel(1.0, 0.25) - main_bgr).max() <= 2  # inside the 10 cm wide main pipe
    assert np.abs(pixel(1.0 + 0.04, 0.25) - main_bgr).max() <= 2
    assert np.abs(pixel(1.0 + 0.07, 0.25) - main_bgr).max() > 50  # beyond its radius
    truth_column = image[MARGIN_PX + int(0.05 * scale) : MARGIN_PX + int(0.95 * scale), MARGIN_PX + int(0.5 * scale)]
    grey = np.all(np.abs(truth_column.astype(int) - 110) < 40, axis=1)
    dashes = np.count_nonzero(np.diff(grey.astype(int)) == 1)
    assert 0.5 < np.mean(grey) < 0.9 and dashes >= 20  # dashed: ~27 dashes of 9 px over 405 px
    assert pixel(0.25, 0.5)[0] > pixel(0.25, 0.5)[2] + 40  # the survey line (light blue, BGR)


def test_topdown_refuses_an_empty_extent(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="extent"):
        render_topdown(tmp_path / "map.png", reconstruction(), (1.0, 1.0, 0.0, 1.0))


def test_pipes_json_reads_back_as_pipe_models_and_refuses_other_files(tmp_path: Path) -> None:
    recon = reconstruction()
    write_pipes_json(tmp_path / "pipes.json", recon, {"run": "r"})
    back = read_pipes_json(tmp_path / "pipes.json")
    assert len(back) == 2
    for got, want in zip(back, recon.pipes, strict=True):
        np.testing.assert_allclose(got.axis, want.axis, atol=1e-6)
        assert got.diameter_m == pytest.approx(want.diameter_m, abs=1e-6)
        assert got.ends_on == want.ends_on
    (tmp_path / "other.json").write_text('{"format": "something-else"}')
    with pytest.raises(DataFormatError, match="not a gprbot pipes file"):
        read_pipes_json(tmp_path / "other.json")
    (tmp_path / "cut.json").write_text((tmp_path / "pipes.json").read_text()[:100])
    with pytest.raises(DataFormatError, match="unreadable pipes file"):
        read_pipes_json(tmp_path / "cut.json")
