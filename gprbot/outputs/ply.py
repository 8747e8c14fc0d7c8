"""PLY point clouds: the writer (binary_little_endian 1.0, float32 x y z, optional uchar colours) and a
strict reader for replay and evaluation, which also reads ASCII and big-endian vertex data.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from gprbot.atomic_files import atomic_open
from gprbot.errors import DataFormatError

PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
BYTE_ORDER = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": "<"}
MAX_HEADER_BYTES = 1 << 16
COLOUR_NAMES = ("red", "green", "blue")


def write_ply(
    path: str | os.PathLike[str],
    points: NDArray[np.float64],
    colors: NDArray[np.uint8] | None = None,
    comments: Sequence[str] = (),
) -> None:
    """Write points (N, 3) and optional colours (N, 3) uint8 as a binary little-endian PLY, atomically."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"write_ply: points must be (N, 3), got {pts.shape}")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        cols = np.asarray(colors)
        if cols.shape != pts.shape or cols.dtype != np.uint8:
            raise ValueError(f"write_ply: colors must be uint8 {pts.shape}, got {cols.dtype} {cols.shape}")
        fields += [(name, "u1") for name in COLOUR_NAMES]
    for comment in comments:
        if "\n" in comment or "\r" in comment or not comment.isascii():
            raise ValueError(f"write_ply: a comment must be one line of ASCII, got {comment!r}")
    vertices = np.empty(len(pts), dtype=np.dtype(fields))
    for axis, name in enumerate("xyz"):
        vertices[name] = pts[:, axis]
    if colors is not None:
        for channel, name in enumerate(COLOUR_NAMES):
            vertices[name] = cols[:, channel]
    lines = ["ply", "format binary_little_endian 1.0", *(f"comment {c}" for c in comments)]
    lines += [f"element vertex {len(pts)}", *(f"property {_ply_name(t)} {n}" for n, t in fields), "end_header"]
    with atomic_open(path) as handle:
        handle.write(("\n".join(lines) + "\n").encode("ascii"))
        handle.write(vertices.tobytes())


def _ply_name(numpy_type: str) -> str:
    return {"<f4": "float", "u1": "uchar"}[numpy_type]


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    properties: list[tuple[str, str]]  # (name, numpy type); type "list" for list properties


def _parse_header(data: bytes, source: str) -> tuple[str, list[_Element], int]:
    """(format, elements, offset of the body) from the start of a PLY file."""
    if not data.startswith(b"ply"):
        raise DataFormatError(f"{source}: not a PLY file (it must start with 'ply')")
    end = data.find(b"end_header", 0, MAX_HEADER_BYTES)
    newline = data.find(b"\n", end) if end >= 0 else -1
    if end < 0 or newline < 0:
        raise DataFormatError(f"{source}: PLY header has no end_header line; the file is truncated or corrupt")
    try:
        lines = [line.strip() for line in data[:end].decode("ascii").splitlines()[1:]]
    except UnicodeDecodeError as exc:
        raise DataFormatError(f"{source}: PLY header is not ASCII; the file is corrupt") from exc
    fmt = ""
    elements: list[_Element] = []
    for line in lines:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) == 3 and words[1] in BYTE_ORDER:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append(_Element(words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in PLY_TYPES:
            elements[-1].properties.append((words[2], PLY_TYPES[words[1]]))
        elif words[0] == "property" and elements and len(words) == 5 and words[1] == "list":
            elements[-1].properties.append((words[4], "list"))
        else:
            raise DataFormatError(f"{source}: PLY header line {line!r} is not understood")
    if not fmt:
        raise DataFormatError(f"{source}: PLY header has no valid 'format' line")
    return fmt, elements, newline + 1


def _row_dtype(element: _Element, order: str, source: str) -> np.dtype[np.void]:
    if any(t == "list" for _, t in element.properties):
        raise DataFormatError(f"{source}: list properties in element {element.name!r} are not supported here")
    return np.dtype([(name, order + t) for name, t in element.properties])


def _read_vertices(data: bytes, fmt: str, elements: list[_Element], body: int, source: str) -> NDArray[np.void]:
    """The vertex element's rows as a structured array."""
    index = next((i for i, e in enumerate(elements) if e.name == "vertex"), None)
    if index is None:
        raise DataFormatError(f"{source}: PLY file has no vertex element")
    vertex = elements[index]
    dtype = _row_dtype(vertex, BYTE_ORDER[fmt], source)
    if fmt == "ascii":
        rows = data[body:].decode("ascii", errors="replace").splitlines()
        skip = sum(e.count for e in elements[:index])
        table = [row.split() for row in rows[skip : skip + vertex.count]]
        if len(table) < vertex.count or any(len(r) != len(dtype.names or ()) for r in table):
            raise DataFormatError(f"{source}: PLY vertex data is truncated or malformed")
        try:
            values = np.array(table, dtype=np.float64).reshape(vertex.count, len(dtype.names or ()))
        except ValueError as exc:
            raise DataFormatError(f"{source}: PLY vertex data is not numeric ({exc})") from exc
        out = np.empty(vertex.count, dtype=dtype)
        for column, name in enumerate(dtype.names or ()):
            out[name] = values[:, column]
        return out
    offset = body + sum(e.count * _row_dtype(e, "<", source).itemsize for e in elements[:index])
    after = elements[index + 1 :]
    expected = offset + vertex.count * dtype.itemsize
    if len(data) < expected:
        raise DataFormatError(
            f"{source}: PLY file is truncated ({len(data)} bytes, the header needs at least {expected})"
        )
    if all("list" not in {t for _, t in e.properties} for e in after):
        total = expected + sum(e.count * _row_dtype(e, "<", source).itemsize for e in after)
        if len(data) != total:
            raise DataFormatError(f"{source}: PLY file has {len(data)} bytes, its header says {total}")
    return np.frombuffer(data, dtype=dtype, count=vertex.count, offset=offset)


def read_ply(path: str | os.PathLike[str]) -> tuple[NDArray[np.float64], NDArray[np.uint8] | None]:
    """Read a PLY's vertices: points (N, 3) float64 and colours (N, 3) uint8, or None without colours."""
    source = os.fspath(path)
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise DataFormatError(f"cannot read PLY file {source}: {exc.strerror}") from exc
    fmt, elements, body = _parse_header(data, source)
    vertices = _read_vertices(data, fmt, elements, body, source)
    names = vertices.dtype.names or ()
    if not {"x", "y", "z"} <= set(names):
        raise DataFormatError(f"{source}: PLY vertices need x, y and z properties, got {names}")
    points = np.column_stack([vertices[n].astype(np.float64) for n in "xyz"]).reshape(-1, 3)
    if not np.all(np.isfinite(points)):
        raise DataFormatError(f"{source}: PLY file holds non-finite coordinates; it is corrupt")
    if not set(COLOUR_NAMES) <= set(names):
        return points, None
    if any(vertices[n].dtype.kind not in "iu" for n in COLOUR_NAMES):
        raise DataFormatError(f"{source}: PLY colours must be integer properties (uchar)")
    colours = np.column_stack([np.clip(vertices[n], 0, 255) for n in COLOUR_NAMES]).astype(np.uint8)
    return points, colours.reshape(-1, 3)
