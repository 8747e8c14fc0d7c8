"""SEG-Y rev 1 (as GPR programs write it) read and write through segyio; times follow su.dt_from_field.

Files we write: IEEE float32 samples (format 5), big-endian, one trace per GPR trace, CDP X the
distance along the line in mm (scalar -1000), dt in ps, and "GPRBOT" lines in the textual header
with the exact sample interval, time zero, frequency and separation, which our reader prefers.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import segyio

from gprbot.errors import DataFormatError
from gprbot.gpr.formats.radargram import (
    Radargram,
    check_dt,
    check_size,
    plausible_frequency,
    plausible_separation,
    positions_mm,
    read_bytes,
    write_atomically,
)
from gprbot.gpr.formats.su import coordinate_positions, dt_from_field

REEL_BYTES = 3600
FORMAT_BYTES = {1: 4, 2: 4, 3: 2, 5: 4, 6: 8, 8: 1, 10: 4, 11: 2, 16: 1}  # segyio's sample formats
_KEYS = ("DT_NS", "TIME_ZERO_NS", "FREQUENCY_MHZ", "SEPARATION_M")
_TF = segyio.TraceField


def segy_layout(raw: bytes) -> tuple[str, int, int, int] | None:
    """(byte order, samples, format code, extended textual headers) if `raw` has a SEG-Y reel header."""
    if len(raw) < REEL_BYTES:
        return None
    for endian in (">", "<"):
        ns, fmt = (int(v) for v in np.frombuffer(raw, endian + "u2", count=3, offset=3220)[[0, 2]])
        ext = int(np.frombuffer(raw, endian + "i2", count=1, offset=3504)[0])
        if fmt in FORMAT_BYTES and ns > 0 and 0 <= ext <= 100:
            return endian, ns, fmt, ext
    return None


def _text_keys(text: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for key in _KEYS:
        m = re.search(rf"GPRBOT {key} ([-+0-9.eE]+)", text)
        if m:
            try:
                out[key] = float(m.group(1))
            except ValueError:
                continue
    return out


def read_segy(path: Path, *, allow_partial: bool = False) -> Radargram:
    """A SEG-Y file (rev 0/1, either byte order) through segyio, checked against its size first."""
    src = str(path)
    raw = read_bytes(path, "SEG-Y file")
    layout = segy_layout(raw)
    if layout is None:
        raise DataFormatError(f"{src}: no SEG-Y binary header (sample count, format code 1-16); not a SEG-Y file")
    endian, ns, fmt, ext = layout
    check_size(src, 1, ns)
    body = len(raw) - REEL_BYTES - 3200 * ext
    step = 240 + ns * FORMAT_BYTES[fmt]
    traces, extra = divmod(max(body, 0), step)
    if extra or traces == 0:
        raise DataFormatError(
            f"{src}: {body} bytes of traces are not a whole number of {step}-byte traces ({ns} samples, format {fmt}); "
            "the file is truncated, or its traces vary in length, which this reader does not support"
        )
    check_size(src, traces, ns)
    try:
        with segyio.open(src, "r", ignore_geometry=True, endian="big" if endian == ">" else "little") as f:
            data = np.asarray(f.trace.raw[:], dtype=np.float32).reshape(traces, ns)
            text = bytes(f.text[0]).decode("ascii", "replace")
            binary = {str(k): int(v) for k, v in f.bin.items()}
            attrs = {name: np.asarray(f.attributes(getattr(_TF, name))[:], dtype=np.float64) for name in (
                "CDP_X", "CDP_Y", "SourceX", "SourceY", "GroupX", "GroupY")}
            scalar = int(f.attributes(_TF.SourceGroupScalar)[0][0])
            units = int(f.attributes(_TF.CoordinateUnits)[0][0])
            delrt = int(f.attributes(_TF.DelayRecordingTime)[0][0])
            first = {str(k): int(v) for k, v in f.header[0].items() if v}
            trace_dt = int(f.attributes(_TF.TRACE_SAMPLE_INTERVAL)[0][0])
    except (RuntimeError, OSError, ValueError, IndexError, KeyError, TypeError) as exc:
        raise DataFormatError(f"{src}: segyio cannot read this SEG-Y file ({exc}); check it is SEG-Y rev 0/1") from exc
    notes: list[str] = []
    ours = _text_keys(text)
    field = binary.get("Interval", 0) or trace_dt
    dt = ours["DT_NS"] if "DT_NS" in ours else dt_from_field(field, notes, src, ns)
    dt = check_dt(src, dt, ns)
    if not np.isfinite(data).all():
        notes.append("NaN or infinite samples set to 0")
        data = np.nan_to_num(data, nan=0.0, posinf=0.0, neginf=0.0)
    feet = binary.get("MeasurementSystem") == 2
    positions = None
    if units in (2, 3, 4):
        notes.append("coordinates are geographic (arc seconds or degrees): distance along the line not derived")
    else:
        for x, y, what in (("CDP_X", "CDP_Y", "CDP"), ("SourceX", "SourceY", "source")):
            positions = coordinate_positions(attrs[x], attrs[y], scalar, notes, f"{what} coordinate")
            if positions is None and what == "source":
                mx, my = (attrs["SourceX"] + attrs["GroupX"]) / 2, (attrs["SourceY"] + attrs["GroupY"]) / 2
                positions = coordinate_positions(mx, my, scalar, notes, "source/receiver midpoint")
            if positions is not None:
                break
        if positions is not None and feet:
            positions = positions * 0.3048
    if positions is None:
        notes.append("no usable trace coordinates: no distance calibration; pass --spacing")
    t0 = ours.get("TIME_ZERO_NS", -float(delrt) if delrt else None)
    freq = plausible_frequency(ours.get("FREQUENCY_MHZ"), notes, "FREQUENCY_MHZ")
    sep = plausible_separation(ours.get("SEPARATION_M"), notes, "SEPARATION_M")
    header: dict[str, Any] = {"byte_order": "big" if endian == ">" else "little", "format": fmt, "binary": binary,
                              "text": text.strip(), "first_trace_header": first}
    return Radargram(samples=data, dt_ns=dt, source_format="segy", positions_m=positions, time_zero_ns=t0,
                     frequency_mhz=freq, antenna_separation_m=sep, header=header, warnings=tuple(notes))


def write_segy(path: Path, rg: Radargram) -> tuple[list[Path], list[str]]:
    """Write `rg` as SEG-Y rev 1 (big-endian float32) atomically; returns the path and notes."""
    n, m = rg.samples.shape
    dt_ps = round(rg.dt_ns * 1000.0)
    if not 1 <= dt_ps <= 65535 or m > 65535:
        raise DataFormatError(f"cannot write SEG-Y: dt {rg.dt_ns:g} ns or {m} samples do not fit its 16-bit fields")
    notes = [] if abs(dt_ps - rg.dt_ns * 1000.0) < 1e-6 else [
        f"dt field holds {dt_ps} ps (rounded); the exact {rg.dt_ns:.9g} ns is in the textual header"]
    lines = {1: "GPR LINE WRITTEN BY GPRBOT", 2: "TIME: NS STORED AS MS (DT FIELD IN PS)",
             3: "CDP X: DISTANCE ALONG THE LINE IN MM (SCALAR -1000)", 4: f"GPRBOT DT_NS {rg.dt_ns:.12g}"}
    if rg.time_zero_ns is not None:
        lines[5] = f"GPRBOT TIME_ZERO_NS {rg.time_zero_ns:.9g}"
    if rg.frequency_mhz:
        lines[6] = f"GPRBOT FREQUENCY_MHZ {rg.frequency_mhz:.9g}"
    if rg.antenna_separation_m is not None:
        lines[7] = f"GPRBOT SEPARATION_M {rg.antenna_separation_m:.9g}"
    if rg.antenna:
        lines[8] = f"ANTENNA {rg.antenna[:60]}"
    mm = positions_mm(rg.positions_m) if rg.positions_m is not None else np.zeros(n, dtype=np.int64)
    spec = segyio.spec()
    spec.samples, spec.format, spec.tracecount, spec.endian = list(range(m)), 5, n, "big"
    temp = path.with_name(f".{path.name}.segyio.tmp")
    try:
        with segyio.create(str(temp), spec) as f:
            f.text[0] = segyio.tools.create_text_header(lines)
            f.bin.update({segyio.BinField.Interval: dt_ps, segyio.BinField.Samples: m, segyio.BinField.Format: 5,
                          segyio.BinField.MeasurementSystem: 1, segyio.BinField.SEGYRevision: 1,
                          segyio.BinField.TraceFlag: 1, segyio.BinField.Traces: 1})
            for i in range(n):
                f.header[i] = {_TF.TRACE_SEQUENCE_LINE: i + 1, _TF.TRACE_SEQUENCE_FILE: i + 1, _TF.CDP: i + 1,
                               _TF.TraceIdentificationCode: 1, _TF.TRACE_SAMPLE_COUNT: m,
                               _TF.TRACE_SAMPLE_INTERVAL: dt_ps, _TF.SourceGroupScalar: -1000,
                               _TF.CoordinateUnits: 1, _TF.CDP_X: int(mm[i])}
            f.trace.raw[:] = np.ascontiguousarray(rg.samples, dtype=np.float32)
        payload = temp.read_bytes()
    finally:
        temp.unlink(missing_ok=True)
    def fill(out: BinaryIO) -> None:
        out.write(payload)

    write_atomically(path, fill)
    return [path], notes
