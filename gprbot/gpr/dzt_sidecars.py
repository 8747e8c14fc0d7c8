"""The files GSSI units and RADAN write beside a DZT: .DZG (GPS), .DZX (XML metadata), .MRK (marks).

- DZG: NMEA text. Each `$GSSIS,<scan>,<time>` line names the scan (0-based) at which the unit took
  the GPS sentences that follow it (GGA: position and elevation; RMC: position and date). Per-trace
  positions are interpolated linearly by scan number between fixes and are NaN outside them.
- DZX: RADAN 7 / SIR-4000 XML (namespace www.geophysical.com/DZX/1.02). GlobalProperties carry the
  dielectric, units per scan and mark and the horizontal unit; File/Profile/WayPt elements carry
  distance marks (scan → distance) and user marks. Parsed with expat, DTDs and entities refused
  (no entity expansion, no external fetches) and the size capped.
- MRK: the marker list older units write: one line per mark, its first number the 1-based trace.

Each parser raises only DataFormatError; the DZT reader turns that into a warning and reads on.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Any
from xml.parsers import expat

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import DataFormatError

MAX_DZG_BYTES = 64 * 2**20  # an hour of 10 Hz GGA + RMC + GSSIS is ~10 MB
MAX_DZX_BYTES = 16 * 2**20  # real DZX files are kilobytes; picks of a big grid stay far below this
MAX_MRK_BYTES = 2**20
MAX_XML_DEPTH = 64
UNIT_METRES = {"m": 1.0, "meter": 1.0, "meters": 1.0, "cm": 0.01, "mm": 0.001, "km": 1000.0,
               "ft": 0.3048, "feet": 0.3048, "in": 0.0254, "inch": 0.0254, "inches": 0.0254}  # fmt: skip

_NMEA_CHECKSUM = re.compile(r"\*([0-9A-Fa-f]{2})\s*$")


@dataclass(frozen=True)
class GpsTrack:
    """GPS fixes by scan number from a DZG file (WGS84 degrees, elevation in metres, NaN if none)."""

    scans: NDArray[np.int64]
    latitude: NDArray[np.float64]
    longitude: NDArray[np.float64]
    elevation_m: NDArray[np.float64]

    def per_trace(self, traces: int) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(latitude, longitude, elevation) of traces 0..traces-1, interpolated; NaN outside the fixes."""
        k = np.arange(traces, dtype=np.float64)
        inside = (k >= self.scans[0]) & (k <= self.scans[-1])
        out = []
        for values in (self.latitude, self.longitude, self.elevation_m):
            known = np.isfinite(values)
            column = np.full(traces, np.nan)
            if known.any():
                column[inside] = np.interp(k[inside], self.scans[known], values[known])
            out.append(column)
        return out[0], out[1], out[2]


@dataclass(frozen=True)
class DzxWaypoint:
    """One WayPt of a DZX profile: the scan, its kind ("Distance", "User", ...), distance and name."""

    scan: int
    mark: str
    distance: float | None
    name: str


@dataclass(frozen=True)
class DzxInfo:
    """What a DZX sidecar adds to a DZT file."""

    dielectric: float | None
    units_per_scan: float | None
    units_per_mark: float | None
    horizontal_unit: str
    vertical_unit: str
    scan_range: tuple[int, int] | None
    waypoints: tuple[DzxWaypoint, ...]
    target_scans: tuple[int, ...] = ()  # RADAN target picks (TargetWayPt) by scan

    @property
    def unit_m(self) -> float | None:
        """Metres per horizontal unit, None when the unit is not one we know."""
        return UNIT_METRES.get(self.horizontal_unit.strip().lower() or "m")

    def user_marks(self) -> tuple[int, ...]:
        """The scans of the user marks (WayPt mark "User")."""
        return tuple(sorted({w.scan for w in self.waypoints if w.mark.lower() == "user"}))

    def distance_m(self, traces: int) -> tuple[NDArray[np.float64] | None, tuple[str, ...]]:
        """Distance along the line (m) of traces 0..traces-1 from the distance marks, and notes.

        Linear between marks, extended beyond them at the nearest segment's rate. None (with a
        note) when there are fewer than two distance marks, the unit is unknown or the distances
        go backwards.
        """
        points = sorted({w.scan: w.distance for w in self.waypoints if w.distance is not None}.items())
        unit = self.unit_m
        if len(points) < 2:
            return None, ()
        if unit is None:
            return None, (f"DZX horizontal unit {self.horizontal_unit!r} is unknown: distance marks not used",)
        scans = np.array([p[0] for p in points], dtype=np.float64)
        dist = np.array([p[1] for p in points], dtype=np.float64) * unit
        steps = np.diff(dist) / np.diff(scans)
        if (steps < 0).any():
            return None, ("DZX distance marks go backwards along the line: not used",)
        notes = []
        typical = float(np.median(steps))
        odd = (steps > 5 * typical) | (steps < typical / 5) if typical > 0 else np.zeros(len(steps), dtype=bool)
        for j in (int(i) for i in np.flatnonzero(odd)):
            notes.append(
                f"DZX distance marks at scans {int(scans[j])}->{int(scans[j + 1])} move {dist[j + 1] - dist[j]:g} m "
                f"in {int(scans[j + 1] - scans[j])} scans, {steps[j] / typical:.3g}x the line's typical "
                f"{typical:.4g} m/scan: that mark was probably entered by hand"
            )
        k = np.arange(traces, dtype=np.float64)
        out = np.interp(k, scans, dist)
        out[k < scans[0]] = dist[0] + (k[k < scans[0]] - scans[0]) * steps[0]
        out[k > scans[-1]] = dist[-1] + (k[k > scans[-1]] - scans[-1]) * steps[-1]
        return out, tuple(notes)


# --- DZG ---------------------------------------------------------------------------------------


def parse_dzg(raw: bytes, source: str = "<dzg>") -> tuple[GpsTrack, tuple[str, ...]]:
    """GPS fixes by scan from the bytes of a DZG file, with notes on what was skipped.

    Raises DataFormatError when the file holds no usable fix (no $GSSIS lines, no valid GGA/RMC).
    """
    if len(raw) > MAX_DZG_BYTES:
        raise DataFormatError(f"{source}: {len(raw)} bytes is larger than any DZG a unit writes")
    fixes: dict[int, tuple[float, float, float]] = {}
    scan: int | None = None
    skipped = 0
    backwards = False
    last_scan = -1
    for line in raw.decode("latin-1").splitlines():
        line = line.strip()
        if not line.startswith("$"):
            continue
        fields = _nmea_fields(line)
        if fields is None:
            skipped += 1
            continue
        kind = fields[0][-3:].upper() if fields[0].upper() != "GSSIS" else "GSSIS"
        if kind == "GSSIS":
            scan = _int_or_none(fields[1]) if len(fields) > 1 else None
            if scan is None or scan < 0:
                skipped += 1
                scan = None
            else:
                backwards |= scan < last_scan
                last_scan = scan
            continue
        if scan is None or kind not in ("GGA", "RMC"):
            continue
        fix = _gga(fields) if kind == "GGA" else _rmc(fields)
        if fix is None:
            skipped += 1
            continue
        known = fixes.get(scan)
        if known is None or (kind == "GGA" and math.isnan(known[2])):
            fixes[scan] = fix  # GGA (with elevation) wins over RMC of the same scan
    if not fixes:
        raise DataFormatError(f"{source}: no GPS fix tied to a scan ($GSSIS line followed by a valid GGA or RMC)")
    notes = []
    if skipped:
        notes.append(f"{source}: {skipped} DZG line(s) skipped (bad checksum, no fix or unreadable fields)")
    if backwards:
        notes.append(f"{source}: DZG scan numbers go backwards (a paused recording); fixes sorted by scan")
    scans = np.array(sorted(fixes), dtype=np.int64)
    values = np.array([fixes[int(s)] for s in scans], dtype=np.float64).reshape(-1, 3)
    return GpsTrack(scans, values[:, 0].copy(), values[:, 1].copy(), values[:, 2].copy()), tuple(notes)


def _nmea_fields(line: str) -> list[str] | None:
    """The comma-separated fields of an NMEA sentence without '$' and checksum; None if it is wrong."""
    body = line[1:]
    match = _NMEA_CHECKSUM.search(body)
    if match:
        body = body[: match.start()]
        checksum = 0
        for char in body:
            checksum ^= ord(char)
        if checksum != int(match.group(1), 16):
            return None
    return body.split(",")


def _gga(f: list[str]) -> tuple[float, float, float] | None:
    # GGA: time, lat, N/S, lon, E/W, quality, satellites, hdop, altitude, M, ...
    if len(f) < 10 or _int_or_none(f[6]) in (None, 0):
        return None
    lat, lon = _degrees(f[2], f[3], 90), _degrees(f[4], f[5], 180)
    if lat is None or lon is None:
        return None
    altitude = _float_or_none(f[9])
    return lat, lon, altitude if altitude is not None and abs(altitude) < 1e5 else math.nan


def _rmc(f: list[str]) -> tuple[float, float, float] | None:
    # RMC: time, status A/V, lat, N/S, lon, E/W, speed, course, date, ...
    if len(f) < 7 or f[2].upper() != "A":
        return None
    lat, lon = _degrees(f[3], f[4], 90), _degrees(f[5], f[6], 180)
    if lat is None or lon is None:
        return None
    return lat, lon, math.nan


def _degrees(value: str, hemisphere: str, limit: int) -> float | None:
    """NMEA (d)ddmm.mmmm + hemisphere → signed degrees, None when malformed or out of range."""
    number = _float_or_none(value)
    if number is None or number < 0 or hemisphere.upper() not in ("N", "S", "E", "W"):
        return None
    whole, minutes = divmod(number, 100.0)
    degrees = whole + minutes / 60.0
    if minutes >= 60.0 or degrees > limit:
        return None
    return -degrees if hemisphere.upper() in ("S", "W") else degrees


def _float_or_none(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _int_or_none(text: str) -> int | None:
    text = text.strip()
    return int(text) if text.isdigit() and len(text) <= 12 else None


# --- DZX ---------------------------------------------------------------------------------------


def parse_dzx(raw: bytes, source: str = "<dzx>") -> DzxInfo:
    """The DZX sidecar's settings and marks; DataFormatError when it is not well-formed DZX XML."""
    root = safe_xml(raw, source, MAX_DZX_BYTES)
    if _local(root.tag) != "DZX":
        raise DataFormatError(f"{source}: XML root element is <{_local(root.tag)}>, not <DZX>")
    props = next((e for e in root if _local(e.tag) == "GlobalProperties"), None)

    def prop(name: str) -> str:
        if props is None:
            return ""
        found = next((e for e in props if _local(e.tag) == name), None)
        return (found.text or "").strip() if found is not None else ""

    waypoints = []
    for element in root.iter():
        if _local(element.tag) != "WayPt":
            continue
        children = {_local(c.tag): (c.text or "").strip() for c in element}
        scan = _int_or_none(children.get("scan", ""))
        if scan is None:
            continue
        distance = _float_or_none(children.get("distance", "")) if "distance" in children else None
        waypoints.append(DzxWaypoint(scan, children.get("mark", ""), distance, children.get("name", "")))
    targets = []
    for element in root.iter():
        if _local(element.tag) == "scanSampChanProp":
            first = (element.text or "").split(",")[0]
            scan = _int_or_none(first)
            if scan is not None:
                targets.append(scan)
    scan_range = None
    for element in root.iter():
        if _local(element.tag) == "scanRange":
            parts = [_int_or_none(p) for p in (element.text or "").split(",")]
            if len(parts) == 2 and parts[0] is not None and parts[1] is not None:
                scan_range = (parts[0], parts[1])
            break
    return DzxInfo(
        dielectric=_positive(prop("dielectric")),
        units_per_scan=_positive(prop("unitsPerScan")),
        units_per_mark=_positive(prop("unitsPerMark")),
        horizontal_unit=prop("horizontalUnit"),
        vertical_unit=prop("verticalUnit"),
        scan_range=scan_range,
        waypoints=tuple(waypoints),
        target_scans=tuple(targets),
    )


def safe_xml(raw: bytes, source: str, max_bytes: int) -> ET.Element:
    """Parse XML with expat, refusing DTDs, entity declarations and deep nesting (no expansion bombs).

    Raises DataFormatError for anything that is not a small, plain, well-formed XML document.
    """
    if len(raw) > max_bytes:
        raise DataFormatError(f"{source}: {len(raw)} bytes is more than the {max_bytes} bytes allowed for this XML")
    builder = ET.TreeBuilder()
    parser = expat.ParserCreate()
    depth = 0

    def refuse(*_args: Any) -> int:
        raise DataFormatError(f"{source}: XML with a DTD or entity declarations is not accepted")

    def start(tag: str, attrs: dict[str, str]) -> None:
        nonlocal depth
        depth += 1
        if depth > MAX_XML_DEPTH:
            raise DataFormatError(f"{source}: XML nested deeper than {MAX_XML_DEPTH} elements")
        builder.start(tag, attrs)

    def end(tag: str) -> None:
        nonlocal depth
        depth -= 1
        builder.end(tag)

    parser.StartDoctypeDeclHandler = refuse
    parser.EntityDeclHandler = refuse
    parser.UnparsedEntityDeclHandler = refuse
    parser.ExternalEntityRefHandler = refuse
    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = builder.data
    try:
        parser.Parse(raw, True)
        root = builder.close()
    except expat.ExpatError as exc:
        raise DataFormatError(f"{source}: not well-formed XML ({exc})") from exc
    except (AssertionError, ValueError, RecursionError) as exc:  # TreeBuilder on an unbalanced document
        raise DataFormatError(f"{source}: not well-formed XML ({exc or type(exc).__name__})") from exc
    return root


def _local(tag: str) -> str:
    """An element name without its {namespace}."""
    return tag.rsplit("}", 1)[-1]


def _positive(text: str) -> float | None:
    value = _float_or_none(text)
    return value if value is not None and value > 0 else None


# --- MRK ---------------------------------------------------------------------------------------


def parse_mrk(raw: bytes, source: str = "<mrk>") -> tuple[int, ...]:
    """0-based traces of the marks in an .MRK file (first number of each line, 1-based there)."""
    if len(raw) > MAX_MRK_BYTES:
        raise DataFormatError(f"{source}: {len(raw)} bytes is larger than any marker file")
    marks = []
    for line in raw.decode("latin-1").splitlines():
        fields = line.split()
        if not fields:
            continue
        trace = _int_or_none(fields[0])
        if trace is None or trace < 1:
            raise DataFormatError(f"{source}: line {line.strip()!r} does not start with a trace number")
        marks.append(trace - 1)
    if not marks:
        raise DataFormatError(f"{source}: no marks")
    return tuple(sorted(set(marks)))
