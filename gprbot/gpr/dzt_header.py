"""The 1024-byte GSSI DZT channel header: its layout, its variants, its bounds and its summaries.

Layout: GSSI, "RADAN DZT File Format" (struct tagRFHeader, little-endian; also printed in the SIR-30
manual's appendix B), cross-checked against readgssi 0.0.22, GPRPy, ImpDAR and RGPR and against the
real files in ../shared/data/real (SIR-3000, StructureScan Mini, an 8-bit 2003 unit, a SIR-3000
firmware with tag 0x0700). A file holds one such header per channel, then the scans; channel 0's
header describes the file (as every public reader takes it), the others add their antenna names.

Variants the reader accepts (see `is_known_tag`, `data_offset`):
- rh_tag: the low byte marks a header (0xFF; SIR-3000 firmware writes 0x00), the high byte is a
  version nibble: 0x00FF (RADAN, SIR-2000/20/30, StructureScan, UtilityScan), 0x0nFF (SIR-4000
  writes 0x07FF), 0x0n00 (SIR-3000 writes 0x0700), 0xFnFF (the spec's "old file" format). No public
  reader interprets the nibble (readgssi, GPRPy, ImpDAR and RGPR never test rh_tag at all).
- rh_data: < 1024 counts 1024-byte header blocks (extended headers), otherwise the data follow the
  channels' 1024-byte headers; 0 (never set) reads as the latter, with a warning.
- samples: 8- and 16-bit unsigned with the binary offset 2^(bits-1) whatever rh_zero says (SIR-3000
  files store rh_zero 0, the 8-bit 2003 file 128; SIR-30/UtilityScan DF store repeats per sample),
  32-bit signed.

Bounds: header values that size arrays or divide are checked against what real instruments produce
(`BOUNDS`); outside them the file is refused with one line saying what to do. Descriptive fields that
units leave at 0 or fill with nonsense (eps_r, traces per metre or second, position, depth) are read
with a warning in plain words (what it means, what to pass) and a neutral value (0), never refused.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from datetime import datetime

from gprbot.errors import DataFormatError

HEADER_SIZE = 1024  # MINHEADSIZE of the spec: one channel header
MAX_CHANNELS = 16  # GSSI units record 1-4 channels; TerraVision arrays 14: more means a corrupt header
SAMPLE_BITS = (8, 16, 32)  # 8/16-bit unsigned, 32-bit signed (spec: rh_bits)
MIN_SAMPLES, MAX_SAMPLES = 2, 65535  # rh_nsamp is a 16-bit count; samples 0 and 1 are the trace header
MAX_RANGE_NS = 10_000.0  # 10 µs: the longest windows of 10-25 MHz sounding antennas, 1.5 km of air
MIN_DT_NS, MAX_DT_NS = 1e-3, 10.0  # 1 ps (1 THz equivalent sampling) .. 10 ns (100 MHz sampling)
MAX_TRACES_PER_S = 100_000.0  # fastest GSSI units scan at ~800/s; 1e5 leaves room, more is nonsense
MIN_TRACES_PER_M, MAX_TRACES_PER_M = 0.01, 100_000.0  # one trace per 100 m .. per 10 µm
MIN_EPS_R, MAX_EPS_R = 1.0, 100.0  # air .. water (81-88): no ground has a permittivity outside
ANTENNA_FIELD = slice(98, 112)
NAME_FIELD = slice(114, 126)

# The bounds as `gprbot info` users and the note read them: (value, bound, why).
BOUNDS: tuple[tuple[str, str, str], ...] = (
    ("rh_bits", "8, 16, 32", "the only sample types of the format"),
    ("rh_nchan", f"1..{MAX_CHANNELS}", "GSSI units record 1-4 channels, TerraVision arrays 14"),
    ("rh_nsamp", f"{MIN_SAMPLES}..{MAX_SAMPLES}", "a 16-bit count; samples 0-1 are the trace header"),
    ("rhf_range", f"0 < range <= {MAX_RANGE_NS:g} ns", "10 µs: the longest 10-25 MHz sounding windows"),
    ("dt = range / samples", f"{MIN_DT_NS * 1000:g} ps .. {MAX_DT_NS:g} ns", "1 THz .. 100 MHz sampling"),
    ("data offset", "after the channel headers, inside the file", "the rh_data rule of the spec"),
    ("traces", ">= 1 whole scan", "counted from the file size, so never more than the file holds"),
    ("rhf_spm", f"0 or {MIN_TRACES_PER_M:g}..{MAX_TRACES_PER_M:g} /m", "else warning, read as 0"),
    ("rhf_sps", f"0..{MAX_TRACES_PER_S:g} /s", "else warning, read as 0"),
    ("rhf_epsr", f"{MIN_EPS_R:g}..{MAX_EPS_R:g}", "else warning, read as 0 (not set)"),
    ("rhf_position", "|position| <= range", "else warning, read as 0"),
)

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

_FIXED = struct.Struct("<HhHhhfffffh")  # rh_tag .. rh_npass, bytes 0..31
_DATES = struct.Struct("<II")  # rhb_cdt, rhb_mdt, bytes 32..39
_COUNTS = struct.Struct("<HHHHHHh")  # rh_rgain .. rh_nchan, bytes 40..53
_MEDIUM = struct.Struct("<fff")  # rhf_epsr, rhf_top, rhf_depth, bytes 54..65
_MIN_FIXED = 128  # PARAREASIZE: the fixed fields; range gain, text and history come after


@dataclass(frozen=True)
class DztHeader:
    """What a DZT file says about its data (from channel 0's header); traces are per channel."""

    channels: int
    samples: int
    bits: int
    traces: int
    range_ns: float  # rhf_range: the time window
    position_ns: float  # rhf_position (0 when the header's value is nonsense)
    traces_per_m: float  # rhf_spm (0: no distance calibration, a time-triggered survey)
    traces_per_s: float  # rhf_sps (0: not stated)
    eps_r: float  # rhf_epsr (0: not set)
    depth_m: float  # rhf_depth
    antenna: str
    created: datetime | None  # wall-clock time as stored; the file carries no time zone
    modified: datetime | None
    data_offset: int
    system: str | None  # the control unit, e.g. "SIR-3000"; None when the header names none
    tag: int = 0x00FF  # rh_tag as stored
    zero: int = 0  # rh_zero as stored: NOT the binary offset (see module doc)
    marks_per_m: float = 0.0  # rhf_mpm: the spec's metres per mark, units use it as marks per metre
    gps_capable: bool = False  # rh_version 2: the unit had GPS (not that the file has positions)
    gain_db: tuple[float, ...] = ()  # the range-gain breakpoints (dB) spread over the window
    text: str = ""  # the operator's notes block
    antennas: tuple[str, ...] = ()  # rh_antname of every channel's header
    name: str = ""  # rh_name: the file name the unit first gave the file

    @property
    def dt_ns(self) -> float:
        """Sample interval: range_ns / samples, so sample k lies at k * dt_ns after the window start.

        readgssi spreads rhf_range over exactly rh_nsamp samples (its plot extent and
        ns_per_zsample), and GprConfig.dt_ns uses the same time_window / samples convention.
        """
        return self.range_ns / self.samples


def is_known_tag(tag: int) -> bool:
    """Whether rh_tag is one of the header tags DZT files are known to carry (see module doc)."""
    low, high = tag & 0xFF, tag >> 8
    if low == 0xFF:  # 0x00FF, 0x0nFF (SIR-4000's 0x07FF), 0xFnFF (old files)
        return high <= 0x0F or high >> 4 == 0xF
    return low == 0x00 and 0x01 <= high <= 0x0F  # SIR-3000's 0x0n00


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
    """Byte offset of the first scan: the spec's rule, which readgssi, GPRPy and RGPR all apply."""
    # rh_data < 1024 counts 1024-byte header blocks (files with extended headers);
    # otherwise the data follow the channels' 1024-byte headers.
    return HEADER_SIZE * rh_data if 0 < rh_data < HEADER_SIZE else HEADER_SIZE * channels


def parse_header(buf: bytes, source: str) -> tuple[DztHeader, int, tuple[str, ...]]:
    """Parse and check channel 0's header of a whole DZT file: (header, leftover bytes, warnings).

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
    tag, rh_data, samples, bits, zero, sps, spm, mpm, position, range_ns, _npass = _FIXED.unpack_from(buf, 0)
    if not is_known_tag(tag):
        raise DataFormatError(
            f"{source}: not a GSSI DZT file: header tag 0x{tag:04X} is not a DZT tag (0x00FF, 0x0nFF "
            "as SIR-4000 writes, 0x0n00 as SIR-3000 writes, or the old 0xFnFF); check that this is a "
            ".DZT file from a GSSI control unit or RADAN"
        )
    cdt, mdt = _DATES.unpack_from(buf, 32)
    rgain, nrgain, text_at, ntext, _proc, _nproc, channels = _COUNTS.unpack_from(buf, 40)
    eps_r, _top, depth = _MEDIUM.unpack_from(buf, 54)
    _check_sizes(source, bits, channels, samples, range_ns)
    warnings: list[str] = []
    offset = _data_offset_checked(source, buf, rh_data, channels, warnings)
    trace_bytes = channels * samples * bits // 8
    traces, leftover = divmod(len(buf) - offset, trace_bytes)
    system_code = buf[113] >> 3
    text = _text(buf[text_at : text_at + ntext]) if _MIN_FIXED <= text_at < text_at + ntext <= HEADER_SIZE else ""
    floats = _descriptive_fields(sps, spm, eps_r, position, depth, range_ns, warnings)
    header = DztHeader(
        channels=channels,
        samples=samples,
        bits=bits,
        traces=traces,
        range_ns=range_ns,
        position_ns=floats["position"],
        traces_per_m=floats["spm"],
        traces_per_s=floats["sps"],
        eps_r=floats["eps_r"],
        depth_m=floats["depth"],
        antenna=_text(buf[ANTENNA_FIELD]),
        created=decode_date(cdt),
        modified=decode_date(mdt),
        data_offset=offset,
        system=system_name(system_code),
        tag=tag,
        zero=zero,
        marks_per_m=mpm if math.isfinite(mpm) else 0.0,
        gps_capable=buf[113] & 0x7 == 2,
        gain_db=_gain_points(buf, rgain, nrgain),
        text=text.strip(),
        antennas=tuple(_text(buf[98 + HEADER_SIZE * k : 112 + HEADER_SIZE * k]) for k in range(channels)),
        name=_text(buf[NAME_FIELD]),
    )
    return header, leftover, tuple(warnings)


def system_name(code: int) -> str | None:
    """The control unit named by rh_system: None for 0 (synthetic data, RADAN exports, our files)."""
    if code == 0:
        return None
    return SYSTEM_NAMES.get(code, f"GSSI unit (system code {code})")


def _check_sizes(source: str, bits: int, channels: int, samples: int, range_ns: float) -> None:
    """Refuse the values that size the arrays or divide, naming the field, the value and the bound."""
    problems = []
    if bits not in SAMPLE_BITS:
        problems.append(f"rh_bits={bits} (expected 8, 16 or 32)")
    if not 1 <= channels <= MAX_CHANNELS:
        problems.append(f"rh_nchan={channels} (expected 1..{MAX_CHANNELS} channels)")
    if not MIN_SAMPLES <= samples <= MAX_SAMPLES:
        problems.append(f"rh_nsamp={samples} (expected {MIN_SAMPLES}..{MAX_SAMPLES} samples per trace)")
    if not 0.0 < range_ns <= MAX_RANGE_NS:  # also false for NaN
        problems.append(f"rhf_range={range_ns:g} ns (expected 0 < range <= {MAX_RANGE_NS:g} ns)")
    elif samples >= MIN_SAMPLES and not MIN_DT_NS <= range_ns / samples <= MAX_DT_NS:
        problems.append(
            f"rhf_range={range_ns:g} ns over {samples} samples gives a sample interval of "
            f"{range_ns / samples:.3g} ns (real units sample at {MIN_DT_NS * 1000:g} ps..{MAX_DT_NS:g} ns)"
        )
    if problems:
        raise DataFormatError(
            f"{source}: corrupt DZT header: " + "; ".join(problems) + ". No GSSI unit writes this: the "
            "file is damaged or was written by a broken tool; re-export it from RADAN or the control unit"
        )


def _data_offset_checked(source: str, buf: bytes, rh_data: int, channels: int, warnings: list[str]) -> int:
    """The data offset by the rh_data rule, checked against the headers before it and the file size."""
    if rh_data <= 0:
        warnings.append(
            f"rh_data={rh_data} (offset to the data) is not set; the data are read from byte "
            f"{HEADER_SIZE * channels}, after the {channels} channel header(s), as old files lay them out"
        )
    offset = data_offset(rh_data, channels)
    if offset < HEADER_SIZE * channels:
        raise DataFormatError(
            f"{source}: corrupt DZT header: rh_data={rh_data} puts the data at byte {offset}, inside the "
            f"{channels} channel header(s) that end at byte {HEADER_SIZE * channels}; the file is damaged; "
            "re-export it from RADAN or the control unit"
        )
    if len(buf) < offset:
        raise DataFormatError(
            f"{source}: truncated DZT file: its header declares {channels} channel(s) and data from "
            f"byte {offset}, but the file ends at byte {len(buf)} ({offset - len(buf)} bytes missing); "
            "copy the file again from the control unit"
        )
    return offset


def _descriptive_fields(
    sps: float, spm: float, eps_r: float, position: float, depth: float, range_ns: float, warnings: list[str]
) -> dict[str, float]:
    """The fields nothing is sized by: kept when plausible, else 0 with a warning that says what to do."""
    out = {"sps": sps, "spm": spm, "eps_r": eps_r, "position": position, "depth": depth}
    if spm == 0.0:
        warnings.append(
            "traces per metre is 0: a time-triggered survey without an encoder, so the file has no "
            "distance calibration; pass --spacing M (metres between traces) to place the traces"
        )
    elif not MIN_TRACES_PER_M <= spm <= MAX_TRACES_PER_M:
        out["spm"] = 0.0
        warnings.append(
            f"traces per metre {spm:g} is not a distance calibration a unit writes (expected "
            f"{MIN_TRACES_PER_M:g}..{MAX_TRACES_PER_M:g}); it is ignored: pass --spacing M to place the traces"
        )
    if sps == 0.0:
        warnings.append("traces per second is 0 (not stated): trace times are unknown")
    elif not 0.0 < sps <= MAX_TRACES_PER_S:
        out["sps"] = 0.0
        warnings.append(f"traces per second {sps:g} is not a scan rate a unit writes; it is ignored")
    if eps_r == 0.0:
        warnings.append(
            "eps_r is 0 (the unit did not set a permittivity): depths need a wave velocity; it is "
            "estimated from hyperbolas, or pass --velocity M_PER_NS (e.g. 0.1 for moist soil)"
        )
    elif not MIN_EPS_R <= eps_r <= MAX_EPS_R:
        out["eps_r"] = 0.0
        warnings.append(
            f"eps_r {eps_r:g} is not a permittivity (expected {MIN_EPS_R:g}..{MAX_EPS_R:g}); it is ignored: "
            "the velocity is estimated from hyperbolas, or pass --velocity M_PER_NS"
        )
    if not (math.isfinite(position) and abs(position) <= range_ns):
        out["position"] = 0.0
        warnings.append(
            f"rhf_position {position:g} ns lies outside the {range_ns:g} ns window; it is ignored: time "
            "zero is found from the direct wave"
        )
    elif position < 0.0:
        warnings.append(
            f"rhf_position is negative ({position:g} ns): time zero is found from the direct wave, "
            "not taken from the header"
        )
    if not math.isfinite(depth):
        out["depth"] = 0.0
    return out


def _gain_points(buf: bytes, at: int, size: int) -> tuple[float, ...]:
    """The range-gain block: a 16-bit count n, then n float32 dB values; () when absent or garbled."""
    if not (at >= _MIN_FIXED and size >= 2 and at + size <= HEADER_SIZE):
        return ()
    (count,) = struct.unpack_from("<h", buf, at)
    if not 0 < count <= (size - 2) // 4:
        return ()
    values = struct.unpack_from(f"<{count}f", buf, at + 2)
    if not all(math.isfinite(v) and -100.0 <= v <= 200.0 for v in values):
        return ()
    return tuple(values)


def _text(raw: bytes) -> str:
    """A NUL-terminated ASCII header string (undecodable bytes shown as U+FFFD)."""
    return raw.split(b"\0", 1)[0].decode("ascii", errors="replace")


def pack_header(header: DztHeader, file_name: str = "", *, channel: int = 0) -> bytes:
    """One 1024-byte channel header describing `header` (tag 0x00FF, rh_data 1024, rh_zero 0)."""
    buf = bytearray(HEADER_SIZE)
    # rh_zero = 0, as the SIR-3000 writes it: readgssi takes rh_zero as the count of samples to cut
    # from the top of every trace, so the spec's 0x80 would make it drop 128 samples of 8-bit data.
    _FIXED.pack_into(
        buf, 0, 0x00FF, HEADER_SIZE, header.samples, header.bits, 0, header.traces_per_s,
        header.traces_per_m, header.marks_per_m, header.position_ns, header.range_ns, 0,
    )  # fmt: skip
    _DATES.pack_into(buf, 32, encode_date(header.created), encode_date(header.modified))
    _COUNTS.pack_into(buf, 40, 0, 0, 0, 0, 0, 0, header.channels)
    _MEDIUM.pack_into(buf, 54, header.eps_r, 0.0, header.depth_m)
    antenna = header.antennas[channel] if channel < len(header.antennas) else header.antenna
    buf[ANTENNA_FIELD] = antenna.encode("ascii").ljust(14, b"\0")
    buf[113] = 0 << 3 | 1  # rh_system 0 (not a control unit), rh_version 1 (no GPS)
    buf[NAME_FIELD] = file_name.encode("ascii", errors="replace")[:11].ljust(12, b"\0")
    return bytes(buf)


def header_info(header: DztHeader) -> dict[str, object]:
    """The header as plain JSON-ready values (dates as ISO strings), for `gprbot info --json`."""
    return {
        "system": header.system,
        "antenna": header.antenna,
        "antennas": list(header.antennas),
        "channels": header.channels,
        "samples": header.samples,
        "traces": header.traces,
        "bits": header.bits,
        "range_ns": header.range_ns,
        "dt_ns": header.dt_ns,
        "position_ns": header.position_ns,
        "traces_per_m": header.traces_per_m,
        "traces_per_s": header.traces_per_s,
        "marks_per_m": header.marks_per_m,
        "eps_r": header.eps_r,
        "depth_m": header.depth_m,
        "created": header.created.isoformat() if header.created else None,
        "modified": header.modified.isoformat() if header.modified else None,
        "data_offset": header.data_offset,
        "tag": f"0x{header.tag:04X}",
        "gain_db": list(header.gain_db),
        "text": header.text,
        "name": header.name,
    }


def format_info(header: DztHeader) -> str:
    """A human-readable table of the header, as `gprbot info` prints it."""
    kind = "signed" if header.bits == 32 else "unsigned"
    antennas = ", ".join(a.strip() for a in header.antennas) if len(header.antennas) > 1 else header.antenna.strip()
    rows = [
        ("system", header.system or "not stated"),
        ("antenna", antennas or "not stated"),
        ("channels", str(header.channels)),
        ("samples", f"{header.samples} per trace"),
        ("traces", f"{header.traces} per channel"),
        ("bits", f"{header.bits} ({kind})"),
        ("range", f"{header.range_ns:g} ns (dt {header.dt_ns:.5g} ns)"),
        ("traces per metre", f"{header.traces_per_m:g}"),
        ("traces per second", f"{header.traces_per_s:g}"),
        ("eps_r", f"{header.eps_r:g} (depth {header.depth_m:.3g} m)"),
        ("created", f"{header.created:%Y-%m-%d %H:%M:%S}" if header.created else "not stated"),
        ("header tag", f"0x{header.tag:04X}"),
    ]
    if header.gain_db:
        rows.append(("range gain", " ".join(f"{g:g}" for g in header.gain_db) + " dB"))
    if header.text:
        rows.append(("notes", header.text.replace("\n", " / ")))
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"{name:<{width}}  {value}" for name, value in rows)
