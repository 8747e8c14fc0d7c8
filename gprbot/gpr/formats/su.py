"""Seismic Unix (.su): SEG-Y 240-byte trace headers and float32 samples, no 3600-byte reel header.

The time rule shared with SEG-Y (`dt_from_field`): the standard's dt unit is the microsecond, and an
integer number of µs per sample (≤ 1 MHz) cannot sample any GPR signal, so GPR programs (Radar Unix,
MATGPR, ReflexW) store nanoseconds where the standard has milliseconds: the dt field then holds
picoseconds. We always read it so, with a warning. SU's own float `d1` (byte 181) is used instead
when it agrees within 2 % (it is not rounded to a whole ps), and `d2`/`f2` (bytes 189/193) give the
trace spacing and first position when plausible; otherwise the source/receiver coordinates do.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import DataFormatError
from gprbot.gpr.formats.radargram import (
    Radargram,
    check_dt,
    check_size,
    positions_mm,
    read_bytes,
    uniform_positions,
    write_atomically,
)

TRACE_HEADER_BYTES = 240
MAX_TRACE_STEP_M = 5.0  # a larger step between traces is not a GPR trace spacing: units are unclear


def su_header_dtype(endian: str) -> np.dtype[Any]:
    """The SU trace-header fields we use, at their byte offsets, in one byte order."""
    e = endian
    fields = {
        "tracl": (e + "i4", 0), "tracr": (e + "i4", 4), "cdp": (e + "i4", 20), "trid": (e + "i2", 28),
        "offset": (e + "i4", 36), "scalco": (e + "i2", 70), "sx": (e + "i4", 72), "sy": (e + "i4", 76),
        "gx": (e + "i4", 80), "gy": (e + "i4", 84), "counit": (e + "i2", 88), "delrt": (e + "i2", 108),
        "ns": (e + "u2", 114), "dt": (e + "u2", 116), "d1": (e + "f4", 180), "f1": (e + "f4", 184),
        "d2": (e + "f4", 188), "f2": (e + "f4", 192),
    }
    return np.dtype({"names": list(fields), "formats": [f for f, _ in fields.values()],
                     "offsets": [o for _, o in fields.values()], "itemsize": TRACE_HEADER_BYTES})


def su_layout(head: bytes, size: int) -> tuple[str, int] | None:
    """(byte order, samples) if a file of `size` bytes starting with `head` is whole SU traces of one length."""
    if len(head) < TRACE_HEADER_BYTES + 4:
        return None
    for endian in ("<", ">"):
        ns = int(np.frombuffer(head, endian + "u2", count=1, offset=114)[0])
        step = TRACE_HEADER_BYTES + 4 * ns
        if ns <= 0 or size % step:
            continue
        second = int(np.frombuffer(head, endian + "u2", 1, step + 114)[0]) if len(head) >= step + 116 else -1
        if size == step or second == ns:
            return endian, ns
    return None


def dt_from_field(field: int, notes: list[str], src: str, samples: int) -> float:
    """The sample interval (ns) of a SEG-Y/SU dt field, read as picoseconds (see the module docstring)."""
    if field <= 0:
        raise DataFormatError(f"{src}: the sample interval field is {field}; the header is corrupt")
    dt = field / 1000.0
    notes.append(
        f"dt field {field} read as {field} ps ({dt:g} ns, window {dt * samples:g} ns): GPR programs store ns "
        f"where SEG-Y has ms; the standard's µs would give a {field * samples / 1000:g} ms window"
    )
    return dt


def coordinate_positions(
    x: NDArray[np.float64], y: NDArray[np.float64], scalar: int, notes: list[str], what: str
) -> NDArray[np.float64] | None:
    """Distance along the line from per-trace coordinates (SEG-Y scalar applied), or None if implausible."""
    if len(x) < 2 or not (np.any(x != x[0]) or np.any(y != y[0])):
        return None
    factor = 1.0 if scalar == 0 else (float(scalar) if scalar > 0 else 1.0 / -scalar)
    steps = np.hypot(np.diff(x), np.diff(y)) * factor
    median = float(np.median(steps))
    if not 0 < median <= MAX_TRACE_STEP_M:
        notes.append(
            f"{what} step {median:g} per trace (scalar {scalar}) is not a GPR trace spacing in metres; "
            "positions unknown, pass --spacing"
        )
        return None
    return np.concatenate([[0.0], np.cumsum(steps)])


def read_su(path: Path, *, allow_partial: bool = False) -> Radargram:
    """A Seismic Unix file (either byte order, float32 samples)."""
    raw = read_bytes(path, "SU file")
    src = str(path)
    layout = su_layout(raw, len(raw))
    if layout is None:
        if len(raw) >= 116 and allow_partial:
            layout = ("<", int(np.frombuffer(raw, "<u2", count=1, offset=114)[0]))
        else:
            raise DataFormatError(
                f"{src}: not a whole number of Seismic Unix traces (240-byte header + ns float32 samples); "
                "the file is truncated or not SU — copy it again, or pass --allow-partial"
            )
    endian, ns = layout
    check_size(src, 1, ns)
    step = TRACE_HEADER_BYTES + 4 * ns
    traces = len(raw) // step
    check_size(src, traces, ns)
    rec = np.frombuffer(raw, np.dtype([("h", su_header_dtype(endian)), ("d", endian + "f4", (ns,))]), count=traces)
    h = rec["h"]
    notes: list[str] = []
    dt_field = int(h["dt"][0])
    d1 = float(h["d1"][0])
    dt = dt_from_field(dt_field, notes, src, ns) if dt_field > 0 else 0.0
    if np.isfinite(d1) and d1 > 0 and (dt == 0.0 or abs(d1 - dt) <= 0.02 * dt):
        notes.append(f"used SU d1 = {d1:.9g} ns as the sample interval (the dt field is rounded)")
        dt = d1
    dt = check_dt(src, dt, ns)
    samples = np.ascontiguousarray(rec["d"], dtype=np.float32)
    if not np.isfinite(samples).all():
        notes.append("NaN or infinite samples set to 0")
        samples = np.nan_to_num(samples, nan=0.0, posinf=0.0, neginf=0.0)
    positions = None
    d2, f2 = float(h["d2"][0]), float(h["f2"][0])
    if np.isfinite(d2) and 0 < d2 <= MAX_TRACE_STEP_M:
        positions = uniform_positions(traces, d2, f2 if np.isfinite(f2) and abs(f2) < 1e7 else 0.0)
    else:
        mid_x = (h["sx"].astype(np.float64) + h["gx"]) / 2
        mid_y = (h["sy"].astype(np.float64) + h["gy"]) / 2
        positions = coordinate_positions(mid_x, mid_y, int(h["scalco"][0]), notes, "source/receiver midpoint")
        if positions is None:
            notes.append("no trace spacing (d2) or coordinates: no distance calibration; pass --spacing")
    t0 = -float(h["delrt"][0]) if h["delrt"][0] != 0 else None
    header = {"byte_order": "little" if endian == "<" else "big", "first_trace_header": _first(h)}
    return Radargram(samples=samples, dt_ns=dt, source_format="su", positions_m=positions, time_zero_ns=t0,
                     header=header, warnings=tuple(notes))


def _first(h: NDArray[Any]) -> dict[str, Any]:
    return {name: np.asarray(h[name][0]).item() for name in h.dtype.names or ()}


def write_su(path: Path, rg: Radargram) -> tuple[list[Path], list[str]]:
    """Write `rg` as little-endian SU: float32 samples, dt in ps, d1/d2/f2 and mm coordinates."""
    notes: list[str] = []
    dt_ps = round(rg.dt_ns * 1000.0)
    if not 1 <= dt_ps <= 65535 or rg.n_samples > 65535:
        raise DataFormatError(f"cannot write SU: dt {rg.dt_ns:g} ns or {rg.n_samples} samples do not fit the header")
    n, m = rg.samples.shape
    rec = np.zeros(n, np.dtype([("h", su_header_dtype("<")), ("d", "<f4", (m,))]))
    h = rec["h"]
    h["tracl"] = h["tracr"] = h["cdp"] = np.arange(1, n + 1)
    h["trid"], h["ns"], h["dt"], h["d1"], h["counit"], h["scalco"] = 1, m, dt_ps, rg.dt_ns, 1, -1000
    if rg.positions_m is not None:
        h["sx"] = h["gx"] = positions_mm(rg.positions_m)
        h["d2"], h["f2"] = rg.spacing_m() or 0.0, rg.positions_m[0]
    if rg.antenna_separation_m is not None:
        h["offset"] = round(rg.antenna_separation_m * 1000.0)
    if rg.time_zero_ns is not None:
        h["delrt"] = round(-rg.time_zero_ns)
        notes.append(f"time zero {rg.time_zero_ns:g} ns stored to the whole ns (delrt)")
    rec["d"] = rg.samples

    def fill(f: BinaryIO) -> None:
        f.write(rec.tobytes())

    write_atomically(path, fill)
    return [path], notes
