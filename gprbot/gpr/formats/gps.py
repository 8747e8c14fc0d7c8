"""The Sensors & Software .GPS sidecar: "Trace #N at position P" lines, each followed by NMEA sentences."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import DataFormatError
from gprbot.gpr.formats.radargram import read_text

_TRACE = re.compile(r"trace\s*#\s*(\d+)", re.IGNORECASE)


def nmea_degrees(value: str, hemisphere: str) -> float:
    """An NMEA (d)ddmm.mmmm field and its hemisphere letter as signed decimal degrees."""
    raw = float(value)
    degrees = int(raw // 100)
    out = degrees + (raw - 100 * degrees) / 60.0
    return -out if hemisphere.upper() in ("S", "W") else out


def parse_gga(sentence: str) -> tuple[float, float, float] | None:
    """(latitude, longitude, altitude) of a GGA sentence with a fix, or None."""
    fields = sentence.split("*")[0].split(",")
    if len(fields) < 10 or not fields[0].endswith("GGA") or fields[6] in ("", "0"):
        return None
    try:
        lat, lon = nmea_degrees(fields[2], fields[3]), nmea_degrees(fields[4], fields[5])
        alt = float(fields[9]) if fields[9] else float("nan")
    except ValueError:
        return None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        return None
    return lat, lon, alt


def read_gps_sidecar(path: Path, trace_numbers: NDArray[np.float64], notes: list[str]) -> NDArray[np.float64] | None:
    """Per-trace (lat, lon, alt) interpolated from a .GPS file; None (with a note) when it has no fix."""
    try:
        text = read_text(path, "GPS sidecar")
    except DataFormatError as exc:
        notes.append(f"GPS sidecar ignored: {exc}")
        return None
    fixes: list[tuple[float, float, float, float]] = []
    trace: int | None = None
    for line in text.splitlines():
        m = _TRACE.search(line)
        if m:
            trace = int(m.group(1))
        elif trace is not None and "GGA" in line:
            fix = parse_gga(line[line.find("$") + 1 :] if "$" in line else line)
            if fix is not None:
                fixes.append((float(trace), *fix))
                trace = None
    if not fixes:
        notes.append(f"GPS sidecar {path.name} holds no GGA fix tagged with a trace; ignored")
        return None
    table = np.array(sorted(fixes))
    keep = np.concatenate([[True], np.diff(table[:, 0]) > 0])
    table = table[keep]
    out = np.full((len(trace_numbers), 3), np.nan)
    inside = (trace_numbers >= table[0, 0]) & (trace_numbers <= table[-1, 0])
    for k in range(3):
        out[inside, k] = np.interp(trace_numbers[inside], table[:, 0], table[:, k + 1])
    return out
