"""The 1024-byte GSSI DZT channel header: its layout, its sanity checks, and its summaries.

Layout: GSSI, "RADAN DZT File Format" (6.14.2016), struct tagRFHeader, little-endian, cross-checked
field by field against readgssi 0.0.22 (`readgssi.dzt.readdzt`) and a real SIR-3000 file.
A file holds one such header per channel, then the scans; only channel 0's header is interpreted
(as readgssi does), the others are only required to be present.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from datetime import datetime

from gprbot.errors import DataFormatError

HEADER_SIZE = 1024  # MINHEADSIZE of the spec: one channel header
MAX_CHANNELS = 16  # far beyond any GSSI unit; a larger count means a corrupt header
MAX_RANGE_NS = 100_000.0  # 100 µs is 15 km of air: any larger time window is corrupt
SAMPLE_BITS = (8, 16, 32)  # 8/16-bit unsigned, 32-bit signed (spec: rh_bits)
ANTENNA_FIELD = slice(98, 112)
NAME_FIELD = slice(114, 126)

# rh_system (bits 3..7 of byte 113), names as in the spec's table and readgssi's UNIT map.
SYSTEM_NAMES = {
    2: "SIR-2000",
    3: "SIR-3000",
    4: "TerraVision",
    6: "SIR-20",
    7: "StructureScan Mini",
    8: "SIR-4000",
    9: "SIR-30",
    12: "UtilityScan DF",
    13: "HS",
    14: "StructureScan Mini XT",
}

_FIXED = struct.Struct("<HhhhhfffffH")  # rh_tag .. rh_npass, bytes 0..31
_DATES = struct.Struct("<II")  # rhb_cdt, rhb_mdt, bytes 32..39
_COUNTS = struct.Struct("<hhhhhhh")  # rh_rgain .. rh_nchan, bytes 40..53
_MEDIUM = struct.Struct("<fff")  # rhf_epsr, rhf_top, rhf_depth, bytes 54..65


@dataclass(frozen=True)
class DztHeader:
    """What a DZT file says about its data (from channel 0's header); traces are per channel."""

    channels: int
    samples: int
    bits: int
    traces: int
    range_ns: float  # rhf_range: the time window
    position_ns: float  # rhf_position
    traces_per_m: float  # rhf_spm
    traces_per_s: float  # rhf_sps
    eps_r: float  # rhf_epsr
    depth_m: float  # rhf_depth
    antenna: str
    created: datetime | None  # wall-clock time as stored; the file carries no time zone
    modified: datetime | None
    data_offset: int
    system: str | None  # the control unit, e.g. "SIR-3000"; None when the header names none

    @property
    def dt_ns(self) -> float:
        """Sample interval: range_ns / samples, so sample k lies at k * dt_ns after the window start.

        readgssi spreads rhf_range over exactly rh_nsamp samples (its plot extent and
        ns_per_zsample), and GprConfig.dt_ns uses the same time_window / samples convention.
        """
        return self.range_ns / self.samples


def is_known_tag(tag: int) -> bool:
    """Whether rh_tag is one of the header tags DZT files are known to carry."""
    low, high = tag & 0xFF, tag >> 8
    if low == 0xFF:  # spec: 0x00FF for a header, 0xFnFF for an older file
        return high == 0x00 or high >> 4 == 0xF
    # SIR-3000 writes 0x0n00 (0x0700 in the reference file), which the spec does not list.
    return low == 0x00 and 0x01 <= high <= 0x0F


def decode_date(raw: int) -> datetime | None:
    """A tagRFDate bit field (sec/2:5 min:6 hour:5 day:5 month:4 year-1980:7, LSB first), or None."""
    fields = (
        1980 + (raw >> 25),
        (raw >> 21) & 0xF,
        (raw >> 16) & 0x1F,
        (raw >> 11) & 0x1F,
        (raw >> 5) & 0x3F,
        (raw & 0x1F) * 2,
    )
    try:
        return datetime(*fields)
    except ValueError:  # zero (never set) or garbage: month 0, hour 31, second 60, ...
        return None


def encode_date(when: datetime | None) -> int:
    """The tagRFDate bit field of a wall-clock time (seconds floored to even; 0 for None)."""
    if when is None:
        return 0
    if not 1980 <= when.year <= 2107:
        raise DataFormatError(f"cannot store date {when:%Y-%m-%d} in a DZT header: years 1980-2107 only")
    return (
        (when.year - 1980) << 25
        | when.month << 21
        | when.day << 16
        | when.hour << 11
        | when.minute << 5
        | when.second // 2
    )


def data_offset(rh_data: int, channels: int) -> int:
    """Byte offset of the first scan: spec and readgssi both use this rule for rh_data."""
    # rh_data < 1024 counts 1024-byte header blocks (files with extended headers);
    # otherwise the data follow the channels' 1024-byte headers.
    return HEADER_SIZE * rh_data if rh_data < HEADER_SIZE else HEADER_SIZE * channels


def parse_header(buf: bytes, source: str) -> tuple[DztHeader, int]:
    """Parse and check channel 0's header of a whole DZT file; returns (header, leftover bytes).

    `traces` counts whole scans; the leftover bytes are a partial scan at the end (the caller
    decides whether that is an error). Raises DataFormatError saying what is wrong and what to do.
    """
    if len(buf) < HEADER_SIZE:
        what = "empty (0 bytes)" if not buf else f"{len(buf)} bytes long"
        raise DataFormatError(
            f"{source}: not a complete DZT file: it is {what}, shorter than one {HEADER_SIZE}-byte "
            f"channel header ({HEADER_SIZE - len(buf)} bytes missing); copy the file again from "
            "the control unit"
        )
    tag, rh_data, samples, bits, _zero, sps, spm, _mpm, position, range_ns, _npass = _FIXED.unpack_from(buf, 0)
    if not is_known_tag(tag):
        raise DataFormatError(
            f"{source}: not a GSSI DZT file: header tag 0x{tag:04X} is not a DZT tag "
            "(0x00FF, 0xFnFF or SIR-3000's 0x0n00); check that this is a .DZT file from a GSSI "
            "control unit or RADAN"
        )
    cdt, mdt = _DATES.unpack_from(buf, 32)
    channels = _COUNTS.unpack_from(buf, 40)[6]
    eps_r, _top, depth = _MEDIUM.unpack_from(buf, 54)
    _check_ranges(source, bits, channels, samples, rh_data, (range_ns, sps, spm, position, eps_r, depth))
    offset = data_offset(rh_data, channels)
    if len(buf) < offset:
        raise DataFormatError(
            f"{source}: truncated DZT file: its header declares {channels} channel(s) and data from "
            f"byte {offset}, but the file ends at byte {len(buf)} ({offset - len(buf)} bytes missing); "
            "copy the file again from the control unit"
        )
    trace_bytes = channels * samples * bits // 8
    traces, leftover = divmod(len(buf) - offset, trace_bytes)
    system_code = buf[113] >> 3
    header = DztHeader(
        channels=channels,
        samples=samples,
        bits=bits,
        traces=traces,
        range_ns=range_ns,
        position_ns=position,
        traces_per_m=spm,
        traces_per_s=sps,
        eps_r=eps_r,
        depth_m=depth,
        antenna=_text(buf[ANTENNA_FIELD]),
        created=decode_date(cdt),
        modified=decode_date(mdt),
        data_offset=offset,
        system=None if system_code == 0 else SYSTEM_NAMES.get(system_code, f"GSSI unit {system_code}"),
    )
    return header, leftover


def _check_ranges(source: str, bits: int, channels: int, samples: int, rh_data: int, floats: tuple[float, ...]) -> None:
    """Reject header values no real file has, naming the field and the value."""
    range_ns, sps, spm, position, eps_r, depth = floats
    problems = []
    if bits not in SAMPLE_BITS:
        problems.append(f"rh_bits={bits} (expected 8, 16 or 32)")
    if not 1 <= channels <= MAX_CHANNELS:
        problems.append(f"rh_nchan={channels} (expected 1..{MAX_CHANNELS})")
    if samples < 1:
        problems.append(f"rh_nsamp={samples} (expected a positive count)")
    if not 0.0 < range_ns <= MAX_RANGE_NS:  # also false for NaN
        problems.append(f"rhf_range={range_ns} ns (expected 0 < range <= {MAX_RANGE_NS:g})")
    if not (math.isfinite(sps) and sps >= 0.0):
        problems.append(f"rhf_sps={sps} (expected a finite rate >= 0)")
    if not (math.isfinite(spm) and spm >= 0.0):
        problems.append(f"rhf_spm={spm} (expected a finite density >= 0)")
    if not math.isfinite(position):
        problems.append(f"rhf_position={position}")
    if not (math.isfinite(eps_r) and eps_r > 0.0):
        problems.append(f"rhf_epsr={eps_r} (expected a finite permittivity > 0)")
    if not math.isfinite(depth):
        problems.append(f"rhf_depth={depth}")
    if 1 <= channels <= MAX_CHANNELS and data_offset(rh_data, channels) < HEADER_SIZE * channels:
        problems.append(f"rh_data={rh_data} puts the data inside the {channels} channel header(s)")
    if problems:
        raise DataFormatError(
            f"{source}: corrupt DZT header: " + "; ".join(problems) + ". The file is damaged or was "
            "written by a broken tool; re-export it from RADAN or the control unit"
        )


def _text(raw: bytes) -> str:
    """A NUL-terminated ASCII header string (undecodable bytes shown as U+FFFD)."""
    return raw.split(b"\0", 1)[0].decode("ascii", errors="replace")


def pack_header(header: DztHeader, file_name: str = "") -> bytes:
    """One 1024-byte channel header describing `header` (tag 0x00FF, rh_data 1024, rh_zero 0)."""
    buf = bytearray(HEADER_SIZE)
    # rh_zero = 0, as the SIR-3000 writes it: readgssi takes rh_zero as the count of samples to cut
    # from the top of every trace, so the spec's 0x80 would make it drop 128 samples of 8-bit data.
    _FIXED.pack_into(
        buf, 0, 0x00FF, HEADER_SIZE, header.samples, header.bits, 0, header.traces_per_s,
        header.traces_per_m, 0.0, header.position_ns, header.range_ns, 0,
    )  # fmt: skip
    _DATES.pack_into(buf, 32, encode_date(header.created), encode_date(header.modified))
    _COUNTS.pack_into(buf, 40, 0, 0, 0, 0, 0, 0, header.channels)
    _MEDIUM.pack_into(buf, 54, header.eps_r, 0.0, header.depth_m)
    buf[ANTENNA_FIELD] = header.antenna.encode("ascii").ljust(14, b"\0")
    buf[113] = 0 << 3 | 1  # rh_system 0 (not a control unit), rh_version 1 (no GPS)
    buf[NAME_FIELD] = file_name.encode("ascii", errors="replace")[:11].ljust(12, b"\0")
    return bytes(buf)


def header_info(header: DztHeader) -> dict[str, object]:
    """The header as plain JSON-ready values (dates as ISO strings), for `gprbot info --json`."""
    return {
        "system": header.system,
        "antenna": header.antenna,
        "channels": header.channels,
        "samples": header.samples,
        "traces": header.traces,
        "bits": header.bits,
        "range_ns": header.range_ns,
        "dt_ns": header.dt_ns,
        "position_ns": header.position_ns,
        "traces_per_m": header.traces_per_m,
        "traces_per_s": header.traces_per_s,
        "eps_r": header.eps_r,
        "depth_m": header.depth_m,
        "created": header.created.isoformat() if header.created else None,
        "modified": header.modified.isoformat() if header.modified else None,
        "data_offset": header.data_offset,
    }


def format_info(header: DztHeader) -> str:
    """A human-readable table of the header, as `gprbot info` prints it."""
    kind = "signed" if header.bits == 32 else "unsigned"
    rows = [
        ("system", header.system or "not stated"),
        ("antenna", header.antenna or "not stated"),
        ("channels", str(header.channels)),
        ("samples", f"{header.samples} per trace"),
        ("traces", f"{header.traces} per channel"),
        ("bits", f"{header.bits} ({kind})"),
        ("range", f"{header.range_ns:g} ns (dt {header.dt_ns:.5g} ns)"),
        ("traces per metre", f"{header.traces_per_m:g}"),
        ("traces per second", f"{header.traces_per_s:g}"),
        ("eps_r", f"{header.eps_r:g} (depth {header.depth_m:.3g} m)"),
        ("created", f"{header.created:%Y-%m-%d %H:%M:%S}" if header.created else "not stated"),
    ]
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"{name:<{width}}  {value}" for name, value in rows)
