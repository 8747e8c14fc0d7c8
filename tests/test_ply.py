"""PLY files: our writer read by plyfile (an independent reader), our reader on plyfile's files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

import gprbot.outputs.pipes_json as outputs
from gprbot.errors import DataFormatError
from gprbot.outputs.ply import read_ply, write_ply


@pytest.fixture
def cloud() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    return rng.normal(size=(257, 3)) * [1.0, 0.5, 0.2], rng.integers(0, 256, size=(257, 3), dtype=np.uint8)


def test_written_file_reads_back_identically_with_plyfile(tmp_path: Path, cloud: tuple) -> None:
    points, colours = cloud
    path = tmp_path / "dense.ply"
    write_ply(path, points, colours, comments=["gprbot run 42", "frame: site"])
    ply = PlyData.read(str(path))
    assert not ply.text and ply.byte_order == "<"
    assert ply.comments == ["gprbot run 42", "frame: site"]
    vertex = ply["vertex"]
    assert [p.name for p in vertex.properties] == ["x", "y", "z", "red", "green", "blue"]
    assert vertex["x"].dtype == np.float32 and vertex["red"].dtype == np.uint8
    for axis, name in enumerate("xyz"):
        np.testing.assert_array_equal(vertex[name], points[:, axis].astype(np.float32))
    for channel, name in enumerate(("red", "green", "blue")):
        np.testing.assert_array_equal(vertex[name], colours[:, channel])
    ours, our_colours = read_ply(path)
    np.testing.assert_array_equal(ours, points.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(our_colours, colours)


def test_without_colours_and_without_points(tmp_path: Path, cloud: tuple) -> None:
    points, _ = cloud
    write_ply(tmp_path / "a.ply", points)
    assert [p.name for p in PlyData.read(str(tmp_path / "a.ply"))["vertex"].properties] == ["x", "y", "z"]
    got, colours = read_ply(tmp_path / "a.ply")
    assert colours is None and got.shape == (257, 3)
    write_ply(tmp_path / "empty.ply", np.zeros((0, 3)))
    assert PlyData.read(str(tmp_path / "empty.ply"))["vertex"].count == 0
    empty, _ = read_ply(tmp_path / "empty.ply")
    assert empty.shape == (0, 3)


@pytest.mark.parametrize(("text", "byte_order"), [(False, "<"), (False, ">"), (True, "=")])
def test_our_reader_reads_plyfile_output(tmp_path: Path, cloud: tuple, text: bool, byte_order: str) -> None:
    points, colours = cloud
    vertex = np.empty(
        len(points),
        dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("nx", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")],
    )
    for axis, name in enumerate("xyz"):
        vertex[name] = points[:, axis]
    for channel, name in enumerate(("red", "green", "blue")):
        vertex[name] = colours[:, channel]
    vertex["nx"] = 1.0
    faces = np.array([([0, 1, 2],)], dtype=[("vertex_indices", "i4", (3,))])
    elements = [PlyElement.describe(vertex, "vertex"), PlyElement.describe(faces, "face")]
    path = tmp_path / "theirs.ply"
    PlyData(elements, text=text, byte_order=byte_order, comments=["made by plyfile"]).write(str(path))
    got, got_colours = read_ply(path)
    if text:
        np.testing.assert_allclose(got, points, rtol=1e-6)
    else:
        np.testing.assert_array_equal(got, points)
    np.testing.assert_array_equal(got_colours, colours)


def test_truncated_and_corrupt_files_raise_data_format_error(tmp_path: Path, cloud: tuple) -> None:
    points, colours = cloud
    good = tmp_path / "good.ply"
    write_ply(good, points, colours)
    data = good.read_bytes()
    header_end = data.index(b"end_header\n") + len(b"end_header\n")
    cases = {
        "truncated body": data[:-7],
        "truncated header": data[: header_end - 5],
        "trailing garbage": data + b"\x00" * 15,
        "not a ply": b"solid cube\nfacet normal 0 0 1\n",
        "bad format": data.replace(b"binary_little_endian 1.0", b"binary_middle_endian 1.0"),
        "bad count": data.replace(b"element vertex 257", b"element vertex 2x7"),
        "unknown type": data.replace(b"property float x", b"property quad x"),
        "binary header": b"ply\n\xff\xfe\x00format\nend_header\n",
        "empty": b"",
    }
    for name, content in cases.items():
        path = tmp_path / f"{name.replace(' ', '_')}.ply"
        path.write_bytes(content)
        with pytest.raises(DataFormatError):
            read_ply(path)
    nan_points = points.copy()
    nan_points[3, 1] = np.nan
    write_ply(tmp_path / "nan.ply", nan_points)
    with pytest.raises(DataFormatError, match="non-finite"):
        read_ply(tmp_path / "nan.ply")
    with pytest.raises(DataFormatError, match="cannot read"):
        read_ply(tmp_path / "missing.ply")


def test_failed_write_leaves_the_previous_file_and_no_temp(
    tmp_path: Path, cloud: tuple, monkeypatch: pytest.MonkeyPatch
) -> None:
    points, colours = cloud
    path = tmp_path / "dense.ply"
    write_ply(path, points[:10])
    before = path.read_bytes()

    def disk_full(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(outputs.os, "fsync", disk_full)  # fails after the data went into the temp file
    with pytest.raises(OSError, match="No space"):
        write_ply(path, points, colours)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dense.ply"]


def test_writer_rejects_bad_input(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="points"):
        write_ply(tmp_path / "x.ply", np.zeros((4, 2)))
    with pytest.raises(ValueError, match="colors"):
        write_ply(tmp_path / "x.ply", np.zeros((4, 3)), np.zeros((4, 3), dtype=np.float32))
    with pytest.raises(ValueError, match="comment"):
        write_ply(tmp_path / "x.ply", np.zeros((4, 3)), comments=["two\nlines"])
    assert not list(tmp_path.iterdir())
