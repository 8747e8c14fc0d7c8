"""Sensors & Software pulseEKKO/Noggin DT1 + HD: read and write, with the .GPS sidecar when present.

The .HD is text, "KEY = value" lines after a "1234" marker line. The .DT1 holds, per trace, a 128-byte
header (words 1-8 float32: trace number, position, points, topography, unused, bytes per point, time
window, stacks; words 9-14 three float64 GPS x/y/z; 11 float32: receiver xyz, transmitter xyz, time-zero
adjustment, zero flag, channels, time of day, comment flag; then a 28-byte comment) and its samples:
int16 for 2 bytes per point, float32 for 4 (EKKO_Project). TIMEZERO AT POINT counts points from 1.
"""

from __future__ import annotations

import re
from datetime import date
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import DataFormatError
from gprbot.gpr.formats.gps import read_gps_sidecar
from gprbot.gpr.formats.radargram import (
    Radargram,
    check_dt,
    check_size,
    integer_counts,
    plausible_frequency,
    plausible_separation,
    read_bytes,
    read_text,
    sibling,
    uniform_positions,
    write_atomically,
)

TRACE_HEADER = np.dtype([
    ("trace", "<f4"), ("position", "<f4"), ("points", "<f4"), ("topography", "<f4"), ("unused", "<f4"),
    ("bytes_per_point", "<f4"), ("window_ns", "<f4"), ("stacks", "<f4"),
    ("gps_x", "<f8"), ("gps_y", "<f8"), ("gps_z", "<f8"),
    ("rx", "<f4", (3,)), ("tx", "<f4", (3,)), ("time_zero_adjust", "<f4"), ("zero_flag", "<f4"),
    ("channels", "<f4"), ("time_of_day_s", "<f4"), ("comment_flag", "<f4"), ("comment", "S28"),
])
assert TRACE_HEADER.itemsize == 128
_SAMPLE_TYPES = {2: np.dtype("<i2"), 4: np.dtype("<f4")}
_UNITS_M = {"m": 1.0, "metres": 1.0, "meters": 1.0, "cm": 0.01, "mm": 0.001, "ft": 0.3048, "feet": 0.3048}
SCALE_KEY = "GPRBOT AMPLITUDE SCALE"  # our own HD line: stored counts = value x scale


def parse_hd(text: str) -> dict[str, str]:
    """The KEY = value lines of an .HD file (keys upper-case); free lines under "line N"."""
    out: dict[str, str] = {}
    for k, line in enumerate(ln.strip() for ln in text.splitlines() if ln.strip()):
        key, sep, value = line.partition("=")
        out[key.strip().upper() if sep else f"line {k}"] = value.strip() if sep else line
    return out


def _number(hd: dict[str, str], key: str) -> float | None:
    m = re.match(r"\s*([-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)", hd.get(key, ""))
    return float(m.group(1)) if m else None


def read_dt1(path: Path, *, allow_partial: bool = False) -> Radargram:
    """A DT1 file (given as .DT1 or .HD) with its .HD and .GPS beside it."""
    dt1 = sibling(path, (".dt1",)) if path.suffix.lower() == ".hd" else path
    if dt1 is None:
        raise DataFormatError(f"{path}: no .DT1 data file beside this .HD header; copy both files")
    notes: list[str] = []
    hd_path = sibling(dt1, (".hd",))
    hd = parse_hd(read_text(hd_path, "DT1 header")) if hd_path else {}
    if hd_path is None:
        notes.append("no .HD header beside the .DT1: time zero, frequency and separation unknown")
    raw = read_bytes(dt1, "DT1 file")
    src = str(dt1)
    if len(raw) < TRACE_HEADER.itemsize:
        raise DataFormatError(f"{src}: {len(raw)} bytes is shorter than one 128-byte DT1 trace header; not a DT1 file")
    first = np.frombuffer(raw, TRACE_HEADER, count=1)[0]
    points = float(first["points"])
    if not (np.isfinite(points) and points == int(points)):
        raise DataFormatError(f"{src}: trace header gives {points} points per trace; the file is corrupt")
    n = int(points)
    check_size(src, 1, n)
    bpp = int(first["bytes_per_point"]) if np.isfinite(first["bytes_per_point"]) else 0
    if bpp not in _SAMPLE_TYPES:
        bpp = next((b for b in (2, 4) if len(raw) % (128 + b * n) == 0), 0)
        if not bpp:
            raise DataFormatError(f"{src}: trace header's bytes per point is {first['bytes_per_point']} (2 or 4)")
        notes.append(f"trace header's bytes per point is not 2 or 4; {bpp} fits the file size")
    trace_bytes = TRACE_HEADER.itemsize + bpp * n
    traces, extra = divmod(len(raw), trace_bytes)
    if extra and not allow_partial:
        raise DataFormatError(
            f"{src}: truncated DT1 file: {extra} bytes after {traces} whole traces of {trace_bytes}; "
            "copy it again, or pass --allow-partial to drop the partial trace"
        )
    check_size(src, traces, n)
    record = np.dtype([("h", TRACE_HEADER), ("d", _SAMPLE_TYPES[bpp], (n,))])
    recs = np.frombuffer(raw, record, count=traces)
    samples = np.ascontiguousarray(recs["d"], dtype=np.float32)
    if not np.isfinite(samples).all():
        notes.append("NaN or infinite samples set to 0")
        samples = np.nan_to_num(samples, nan=0.0, posinf=0.0, neginf=0.0)
    scale = _number(hd, SCALE_KEY)
    if scale and np.isfinite(scale) and scale > 0:
        samples /= np.float32(scale)
    stated = _number(hd, "NUMBER OF TRACES")
    if stated is not None and stated != traces:
        notes.append(f"the .HD says {stated:g} traces, the .DT1 holds {traces}; read {traces}")
    pts = _number(hd, "NUMBER OF PTS/TRC")
    if pts is not None and pts != n:
        notes.append(f"the .HD says {pts:g} points per trace, the trace headers {n}; used {n}")
    window = _number(hd, "TOTAL TIME WINDOW") or float(first["window_ns"])
    dt = check_dt(src, window / n, n)
    unit = hd.get("POSITION UNITS", "m").strip().lower() or "m"
    to_m = _UNITS_M.get(unit)
    if to_m is None:
        notes.append(f"position units {unit!r} unknown; read as metres")
        to_m = 1.0
    positions = _positions(recs["h"]["position"].astype(np.float64), hd, to_m, notes)
    t0 = None
    tz = _number(hd, "TIMEZERO AT POINT")
    if tz is not None and 1.0 <= tz <= n:
        t0 = (tz - 1.0) * dt
    elif tz is not None:
        notes.append(f"TIMEZERO AT POINT {tz:g} is outside the trace (1..{n}); time zero unknown")
    freq = plausible_frequency(_number(hd, "NOMINAL FREQUENCY"), notes, "NOMINAL FREQUENCY")
    sep_raw = _number(hd, "ANTENNA SEPARATION")
    sep = plausible_separation(None if sep_raw is None else sep_raw * to_m, notes, "ANTENNA SEPARATION")
    header: dict[str, Any] = {"hd": hd, "bytes_per_point": bpp, "first_trace_header": _header_dict(first)}
    geo = None
    gps_path = sibling(dt1, (".gps",))
    if gps_path is not None:
        geo = read_gps_sidecar(gps_path, recs["h"]["trace"].astype(np.float64), notes)
    return Radargram(
        samples=samples, dt_ns=dt, source_format="dt1", positions_m=positions, time_zero_ns=t0,
        frequency_mhz=freq, antenna_separation_m=sep, antenna=f"{freq:g} MHz" if freq else "",
        header=header, warnings=tuple(notes), geo=geo,
    )


def _positions(
    stated: NDArray[np.float64], hd: dict[str, str], to_m: float, notes: list[str]
) -> NDArray[np.float64] | None:
    """Per-trace positions from the trace headers, else from the .HD's start and step, else None."""
    if len(stated) > 1 and np.isfinite(stated).all() and np.ptp(stated) > 0 and np.abs(stated).max() < 1e7:
        return stated * to_m
    step = _number(hd, "STEP SIZE USED")
    start = _number(hd, "STARTING POSITION") or 0.0
    if step is not None and np.isfinite(step) and 0 < abs(step) < 1e3 and abs(start) < 1e7:
        return uniform_positions(len(stated), step * to_m, start * to_m)
    notes.append("no trace positions and no STEP SIZE USED: no distance calibration; pass --spacing")
    return None


def _header_dict(h: np.void) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name in TRACE_HEADER.names or ():
        v = h[name]
        out[name] = v.decode("latin-1").rstrip("\0 ") if name == "comment" else np.asarray(v).tolist()
    return out


def write_dt1(path: Path, rg: Radargram, *, created: date | None = None) -> tuple[list[Path], list[str]]:
    """Write `rg` as path.DT1 + path.HD (int16 samples); returns the paths and what could not be kept."""
    dt1, hd = path.with_suffix(".DT1"), path.with_suffix(".HD")
    notes: list[str] = []
    counts, scale = integer_counts(rg.samples, 16)
    if scale != 1.0:
        notes.append(f"samples scaled by {scale:.6g} to 16-bit counts (recorded as {SCALE_KEY} in the .HD)")
    n, m = counts.shape
    positions = rg.positions_m if rg.positions_m is not None else np.zeros(n)
    if rg.positions_m is None:
        notes.append("no trace positions: written as 0 (no distance calibration)")
    rec = np.zeros(n, np.dtype([("h", TRACE_HEADER), ("d", "<i2", (m,))]))
    h = rec["h"]
    h["trace"] = np.arange(1, n + 1)
    h["position"] = positions
    h["points"], h["bytes_per_point"], h["window_ns"], h["stacks"], h["channels"] = m, 2, rg.window_ns, 1, 1
    rec["d"] = counts
    step = rg.spacing_m() or 0.0
    lines = [
        "1234", "Data Collected with gprbot", f"{created or date.today():%Y-%m-%d}",
        f"NUMBER OF TRACES   = {n}", f"NUMBER OF PTS/TRC  = {m}",
    ]
    if rg.time_zero_ns is not None:
        lines.append(f"TIMEZERO AT POINT  = {1.0 + rg.time_zero_ns / rg.dt_ns:.6f}")
    lines += [
        f"TOTAL TIME WINDOW  = {rg.window_ns:.6f}", f"STARTING POSITION  = {positions[0]:.6f}",
        f"FINAL POSITION     = {positions[-1]:.6f}", f"STEP SIZE USED     = {step:.6f}", "POSITION UNITS     = m",
    ]
    if rg.frequency_mhz:
        lines.append(f"NOMINAL FREQUENCY  = {rg.frequency_mhz:.6f}")
    if rg.antenna_separation_m is not None:
        lines.append(f"ANTENNA SEPARATION = {rg.antenna_separation_m:.6f}")
    lines += ["NUMBER OF STACKS   = 1", "SURVEY MODE        = Reflection"]
    if scale != 1.0:
        lines.append(f"{SCALE_KEY} = {scale:.9g}")
    text = ("\r\n".join(lines) + "\r\n").encode("ascii", "replace")

    def fill_dt1(f: BinaryIO) -> None:
        f.write(rec.tobytes())

    def fill_hd(f: BinaryIO) -> None:
        f.write(text)

    write_atomically(dt1, fill_dt1)
    write_atomically(hd, fill_hd)
    return [dt1, hd], notes
