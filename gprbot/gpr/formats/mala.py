"""MALÅ RAMAC/ProEx/GX files: RD3 (int16) or RD7 (int32) traces of SAMPLES values, with a .RAD text header.

The .RAD is "KEY:value" lines (some with a space after the colon). FREQUENCY is the sampling frequency
in MHz (dt = 1000 / FREQUENCY ns), not the antenna's; the antenna's centre frequency is in ANTENNAS
("250 MHz shielded"). DISTANCE INTERVAL is the trace spacing (m) when DISTANCE FLAG is 1.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from gprbot.errors import DataFormatError
from gprbot.gpr.formats.radargram import (
    Radargram,
    check_dt,
    check_size,
    plausible_frequency,
    plausible_separation,
    read_bytes,
    read_text,
    sibling,
    uniform_positions,
)

DATA_SUFFIXES: dict[str, np.dtype[Any]] = {".rd3": np.dtype("<i2"), ".rd7": np.dtype("<i4")}


def parse_rad(text: str) -> dict[str, str]:
    """The KEY:value lines of a .RAD header (keys upper-case, values stripped)."""
    out: dict[str, str] = {}
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if sep and key.strip():
            out[key.strip().upper()] = value.strip()
    return out


def _number(rad: dict[str, str], key: str) -> float | None:
    try:
        value = float(rad[key])
    except (KeyError, ValueError):
        return None
    return value if np.isfinite(value) else None


def looks_like_rad(text: str) -> bool:
    """Whether a text is a MALÅ .RAD header (SAMPLES and FREQUENCY keys)."""
    rad = parse_rad(text)
    return "SAMPLES" in rad and "FREQUENCY" in rad


def read_mala(path: Path, *, allow_partial: bool = False) -> Radargram:
    """A MALÅ RD3/RD7 file (given as data or .RAD) with its .RAD header beside it."""
    if path.suffix.lower() == ".rad":
        data_path = sibling(path, tuple(DATA_SUFFIXES))
        rad_path: Path | None = path
    else:
        data_path, rad_path = path, sibling(path, (".rad",))
    if data_path is None:
        raise DataFormatError(f"{path}: no .rd3/.rd7 data file beside this .rad header; copy both files")
    if rad_path is None:
        raise DataFormatError(f"{data_path}: no .rad header beside the MALÅ data file; copy it alongside")
    src = str(data_path)
    rad = parse_rad(read_text(rad_path, "MALÅ header"))
    notes: list[str] = []
    samples = _number(rad, "SAMPLES")
    if samples is None or samples != int(samples):
        raise DataFormatError(f"{rad_path}: SAMPLES is {rad.get('SAMPLES')!r}; the .rad header is corrupt")
    n = int(samples)
    check_size(src, 1, n)
    fs = _number(rad, "FREQUENCY")
    if fs is None or fs <= 0:
        raise DataFormatError(f"{rad_path}: FREQUENCY (sampling, MHz) is {rad.get('FREQUENCY')!r}; header corrupt")
    dt = check_dt(src, 1000.0 / fs, n)
    dtype = DATA_SUFFIXES.get(data_path.suffix.lower(), np.dtype("<i2"))
    if data_path.suffix.lower() not in DATA_SUFFIXES:
        notes.append(f"unknown data suffix {data_path.suffix!r}: read as 16-bit (.rd3)")
    raw = read_bytes(data_path, "MALÅ data file")
    trace_bytes = n * dtype.itemsize
    traces, extra = divmod(len(raw), trace_bytes)
    if extra and not allow_partial:
        raise DataFormatError(
            f"{src}: truncated MALÅ file: {extra} bytes after {traces} traces of {n} samples; check SAMPLES "
            "in the .rad, copy the file again, or pass --allow-partial to drop the partial trace"
        )
    check_size(src, traces, n)
    data = np.frombuffer(raw, dtype, count=traces * n).reshape(traces, n).astype(np.float32)
    last = _number(rad, "LAST TRACE")
    if last is not None and last != traces:
        notes.append(f"LAST TRACE is {last:g}, the file holds {traces} traces; read {traces}")
    window = _number(rad, "TIMEWINDOW")
    if window is not None and abs(window - dt * n) > 0.01 * dt * n:
        notes.append(f"TIMEWINDOW {window:g} ns disagrees with SAMPLES/FREQUENCY ({dt * n:g} ns); used the latter")
    positions = None
    step = _number(rad, "DISTANCE INTERVAL")
    if step is not None and 0 < abs(step) < 1e3:
        start = _number(rad, "START POSITION") or 0.0
        positions = uniform_positions(traces, abs(step), start if abs(start) < 1e7 else 0.0)
    else:
        notes.append("no DISTANCE INTERVAL (a time-triggered file): no distance calibration; pass --spacing")
    antenna = rad.get("ANTENNAS", "")
    m = re.search(r"(\d+(?:\.\d+)?)\s*([MG])Hz", antenna, re.IGNORECASE)
    mhz = None if m is None else float(m.group(1)) * (1000.0 if m.group(2).upper() == "G" else 1.0)
    freq = plausible_frequency(mhz, notes, "ANTENNAS")
    sep = plausible_separation(_number(rad, "ANTENNA SEPARATION"), notes, "ANTENNA SEPARATION")
    header: dict[str, Any] = {"rad": rad, "sampling_frequency_mhz": fs, "bits": 8 * dtype.itemsize}
    return Radargram(
        samples=data, dt_ns=dt, source_format="mala", positions_m=positions, frequency_mhz=freq,
        antenna_separation_m=sep, antenna=antenna, header=header, warnings=tuple(notes),
    )
