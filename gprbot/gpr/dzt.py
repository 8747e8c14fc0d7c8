"""Read and write GSSI DZT radar files (8/16-bit unsigned, 32-bit signed samples, 1..N channels).

A file is one 1024-byte header per channel (see `dzt_header`), then scans: each scan holds one
trace of every channel in turn (channel 0's samples, then channel 1's, ...). Files we write are
read back by readgssi with the same header values and samples (tests/test_dzt*.py check this).

`read_dzt` also reads the sidecars a GSSI unit or RADAN leaves beside the file (same name, .DZG GPS,
.DZX XML, .MRK marks; see `dzt_sidecars`): a broken sidecar is ignored with a note in `warnings`.
Marks come from the trace headers (sample 1 of channel 0, see `trace_header_marks`), else the .MRK
file, else the DZX's user marks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.atomic_files import write_bytes_atomic
from gprbot.errors import DataFormatError
from gprbot.gpr.dzt_header import (
    HEADER_SIZE,
    MAX_DT_NS,
    MAX_EPS_R,
    MAX_RANGE_NS,
    MAX_TRACES_PER_M,
    MAX_TRACES_PER_S,
    MIN_DT_NS,
    MIN_EPS_R,
    MIN_SAMPLES,
    MIN_TRACES_PER_M,
    DztHeader,
    format_info,
    header_info,
    pack_header,
    parse_header,
)
from gprbot.gpr.dzt_sidecars import DzxInfo, GpsTrack, parse_dzg, parse_dzx, parse_mrk
from gprbot.gpr.traveltime import velocity_from_eps

__all__ = [
    "DztFile",
    "DztHeader",
    "dzt_info",
    "format_dzt_info",
    "format_info",
    "header_info",
    "parse_dzt",
    "read_dzt",
    "write_dzt",
]

_STORED_DTYPES: dict[int, np.dtype[Any]] = {8: np.dtype("<u1"), 16: np.dtype("<u2"), 32: np.dtype("<i4")}
_NATIVE_DTYPES: dict[int, type[np.integer[Any]]] = {8: np.uint8, 16: np.uint16, 32: np.int32}
_UNSIGNED_OFFSET = {8: 128, 16: 32768, 32: 0}  # the spec's binary offset of the unsigned formats
WRITE_MAX_CHANNELS = 4  # readgssi keeps per-channel lists of length 4 and fails beyond
WRITE_MAX_SAMPLES = 32767  # readgssi reads rh_nsamp as a signed 16-bit number
MARKER_SAMPLES = 2  # GSSI units store a trace counter and a mark word in samples 0 and 1
MAX_MARK_WORDS = 4  # sample 1 of a trace header takes one value, or a few: signal takes many


@dataclass(frozen=True)
class DztFile:
    """A DZT file's header and samples: one read-only (samples, traces) array per channel.

    `warnings`: what the reader noticed and neutralised (fields left at 0 or nonsense, broken
    sidecars), each saying what it means and what to pass. `marks`: 0-based traces the operator or
    the encoder marked, from `mark_source` ("trace headers", "MRK file", "DZX", or "" for none).
    `gps`: the DZG fixes by scan; `dzx`: the DZX sidecar's settings and marks.
    """

    header: DztHeader
    channels: list[NDArray[Any]]  # dtype as stored: uint8, uint16 or int32
    dropped_bytes: int = 0  # bytes of a trailing partial scan dropped by allow_partial=True
    warnings: tuple[str, ...] = ()
    marks: tuple[int, ...] = ()
    mark_source: str = ""
    gps: GpsTrack | None = None
    dzx: DzxInfo | None = None

    def as_float(self, channel: int = 0) -> NDArray[np.float32]:
        """Channel `channel` as (traces, samples) float32 counts, zero-centred, ready for processing.

        The unsigned formats' binary offset (128 or 32768) is removed. On files from a GSSI control
        unit (header.system set) samples 0 and 1 hold a trace counter and the user-mark word, not
        signal (readgssi reads marks from sample 1 and cuts rh_zero samples for the same reason):
        they are set to 0 here so that they do not show up as a bright band at time zero.
        """
        if not 0 <= channel < len(self.channels):
            raise DataFormatError(
                f"channel {channel} does not exist: this file has {len(self.channels)} channel(s), "
                f"numbered 0..{len(self.channels) - 1}"
            )
        traces = np.ascontiguousarray(self.channels[channel].T, dtype=np.float32)
        traces -= np.float32(_UNSIGNED_OFFSET[self.header.bits])
        if self.header.system is not None:
            traces[:, :MARKER_SAMPLES] = 0.0
        return traces

    def trace_distance_m(self) -> NDArray[np.float64] | None:
        """Distance along the line of every trace: the DZX distance marks, else 1 / traces_per_m.

        None when the file has neither (a time-triggered survey): the caller needs a spacing.
        """
        if self.dzx is not None:
            distance, _notes = self.dzx.distance_m(self.header.traces)
            if distance is not None:
                return distance
        if self.header.traces_per_m > 0.0:
            return np.arange(self.header.traces, dtype=np.float64) / self.header.traces_per_m
        return None

    def trace_positions(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
        """(latitude, longitude, elevation) per trace from the DZG sidecar (NaN outside its fixes)."""
        return None if self.gps is None else self.gps.per_trace(self.header.traces)


def read_dzt(path: str | Path, *, allow_partial: bool = False, sidecars: bool = True) -> DztFile:
    """Read a DZT file; DataFormatError (saying what is wrong and what to do) if it is not sound.

    A file whose data end in a partial scan (a recording cut by power loss) is refused unless
    `allow_partial=True`, which drops the partial scan and records its size in `dropped_bytes`.
    With `sidecars` the .DZG, .DZX and .MRK files beside it are read too (see module doc).
    """
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise DataFormatError(f"cannot read DZT file {path}: {exc.strerror or exc}; check the path") from exc
    dzt = parse_dzt(raw, source=str(path), allow_partial=allow_partial)
    return _with_sidecars(dzt, Path(path)) if sidecars else dzt


def parse_dzt(raw: bytes, *, source: str = "<bytes>", allow_partial: bool = False) -> DztFile:
    """Parse the bytes of a whole DZT file (see read_dzt); `source` names it in error messages.

    Memory: the samples are copied once, per channel (the file's data size); nothing else is sized
    by the header, whose counts are bounded by `dzt_header` and by the file's length.
    """
    header, leftover, warnings = parse_header(raw, source)
    trace_bytes = header.channels * header.samples * header.bits // 8
    if header.traces == 0:
        raise DataFormatError(
            f"{source}: DZT file holds no complete trace: {len(raw) - header.data_offset} data bytes "
            f"after the header, one scan needs {trace_bytes}; the recording is empty or was cut off"
        )
    if leftover and not allow_partial:
        raise DataFormatError(
            f"{source}: truncated DZT file: the data end in a partial scan ({leftover} bytes extra "
            f"after {header.traces} whole scans, {trace_bytes - leftover} bytes missing to complete "
            f"one of {trace_bytes}); copy the file again, or read it with --allow-partial (allow_partial=True) "
            "to drop the partial scan"
        )
    stored = _STORED_DTYPES[header.bits]
    data = np.frombuffer(
        raw, dtype=stored, count=header.traces * trace_bytes // stored.itemsize, offset=header.data_offset
    )
    scans = data.reshape(header.traces, header.channels, header.samples)
    channels = []
    for k in range(header.channels):
        channel = np.ascontiguousarray(scans[:, k, :].T, dtype=_NATIVE_DTYPES[header.bits])
        channel.flags.writeable = False
        channels.append(channel)
    marks = trace_header_marks(header, channels[0])
    return DztFile(
        header=header,
        channels=channels,
        dropped_bytes=leftover,
        warnings=warnings,
        marks=marks,
        mark_source="trace headers" if marks else "",
    )


def trace_header_marks(header: DztHeader, channel0: NDArray[Any]) -> tuple[int, ...]:
    """0-based traces whose mark word (sample 1 of a GSSI unit's trace header) differs from the rest.

    The units write one word on unmarked traces and another on marked ones, in encodings that vary
    by unit: SIR-3000 16-bit 0x0000 / 0x6400, StructureScan Mini 32-bit 0 / 0xE4000000, the 8-bit
    2003 unit 0xF0 / 0xE8. So the common word is the baseline and the others are marks, provided
    sample 1 takes only a few values (signal takes many) and marks are the minority. Files without
    a control unit (header.system None: our own, RADAN exports) have signal there: no marks.
    """
    if header.system is None or header.traces < 2 or header.samples < MARKER_SAMPLES:
        return ()
    words = channel0[1]
    values, counts = np.unique(words, return_counts=True)
    if len(values) > MAX_MARK_WORDS:
        return ()
    marked = np.flatnonzero(words != values[int(np.argmax(counts))])
    if 2 * len(marked) > header.traces:
        return ()
    return tuple(int(k) for k in marked)


def dzt_info(dzt: DztFile) -> dict[str, object]:
    """`header_info` plus marks, sidecars and warnings, JSON-ready, for `gprbot info --json`."""
    info = header_info(dzt.header)
    info["marks"] = list(dzt.marks)
    info["mark_source"] = dzt.mark_source or None
    info["gps_fixes"] = 0 if dzt.gps is None else len(dzt.gps.scans)
    distance = dzt.trace_distance_m()
    info["line_length_m"] = None if distance is None else float(distance[-1] - distance[0])
    info["warnings"] = list(dzt.warnings)
    return info


def format_dzt_info(dzt: DztFile) -> str:
    """`format_info` plus marks, sidecars and one `warning:` line per warning, as `gprbot info` prints."""
    lines = [format_info(dzt.header)]
    if dzt.marks:
        shown = ", ".join(str(k) for k in dzt.marks[:12]) + (", ..." if len(dzt.marks) > 12 else "")
        lines.append(f"marks              {len(dzt.marks)} ({dzt.mark_source}): traces {shown}")
    if dzt.gps is not None:
        lines.append(
            f"gps                {len(dzt.gps.scans)} fixes (.DZG), scans {dzt.gps.scans[0]}..{dzt.gps.scans[-1]}"
        )
    if dzt.dzx is not None:
        lines.append(f"dzx                {len(dzt.dzx.waypoints)} waypoints, dielectric {dzt.dzx.dielectric}")
    lines += [f"warning: {w}" for w in dzt.warnings]
    return "\n".join(lines)


def _with_sidecars(dzt: DztFile, path: Path) -> DztFile:
    """`dzt` with the .DZG/.DZX/.MRK files beside `path` read in; broken ones become warnings."""
    warnings = list(dzt.warnings)
    gps: GpsTrack | None = None
    dzx: DzxInfo | None = None
    mrk: tuple[int, ...] = ()
    traces = dzt.header.traces
    if (found := _sidecar(path, ".DZG")) is not None:
        try:
            gps, notes = parse_dzg(found.read_bytes(), found.name)
            warnings += notes
            if int(gps.scans[-1]) >= traces:
                warnings.append(f"{found.name}: fixes name scans up to {int(gps.scans[-1])}, the file has {traces}")
        except (DataFormatError, OSError) as exc:
            warnings.append(f"{found.name} ignored: {_reason(exc)}")
    if (found := _sidecar(path, ".DZX")) is not None:
        try:
            dzx = parse_dzx(found.read_bytes(), found.name)
            warnings += dzx.distance_m(traces)[1]
        except (DataFormatError, OSError) as exc:
            warnings.append(f"{found.name} ignored: {_reason(exc)}")
    if (found := _sidecar(path, ".MRK")) is not None:
        try:
            mrk = parse_mrk(found.read_bytes(), found.name)
        except (DataFormatError, OSError) as exc:
            warnings.append(f"{found.name} ignored: {_reason(exc)}")
    marks, source = dzt.marks, dzt.mark_source
    if mrk and marks and set(mrk) != set(marks):
        warnings.append(f"the .MRK file's {len(mrk)} marks differ from the {len(marks)} in the trace headers")
    if not marks and mrk:
        marks, source = mrk, "MRK file"
    if not marks and dzx is not None and dzx.user_marks():
        marks, source = dzx.user_marks(), "DZX"
    if dzx is not None:
        warnings = [_with_dzx_hint(w, dzx) for w in warnings]
    return DztFile(dzt.header, dzt.channels, dzt.dropped_bytes, tuple(warnings), marks, source, gps, dzx)


def _sidecar(path: Path, suffix: str) -> Path | None:
    for candidate in (path.with_suffix(suffix), path.with_suffix(suffix.lower())):
        if candidate != path and candidate.is_file():
            return candidate
    return None


def _reason(exc: Exception) -> str:
    if isinstance(exc, OSError):
        return f"cannot read it ({exc.strerror or exc})"
    return str(exc).split(": ", 1)[-1]


def _with_dzx_hint(warning: str, dzx: DzxInfo) -> str:
    """A header warning completed with the value the DZX sidecar holds for the same setting."""
    if warning.startswith("traces per metre") and dzx.units_per_scan and dzx.unit_m:
        return f"{warning} (the .DZX gives {dzx.units_per_scan * dzx.unit_m:g} m per scan)"
    if warning.startswith("eps_r") and dzx.dielectric and MIN_EPS_R <= dzx.dielectric <= MAX_EPS_R:
        return f"{warning} (the .DZX gives dielectric {dzx.dielectric:g})"
    return warning


def write_dzt(
    path: str | Path,
    data: Sequence[NDArray[Any]] | NDArray[Any],
    *,
    range_ns: float,
    bits: int = 16,
    traces_per_m: float = 0.0,
    traces_per_s: float = 0.0,
    eps_r: float = 6.0,
    antenna: str = "",
    created: datetime | None = None,
    position_ns: float = 0.0,
) -> None:
    """Write channels of (samples, traces) to a DZT file atomically (temp file + os.replace).

    `data`: one (samples, traces) array, a (channels, samples, traces) array, or a sequence of
    (samples, traces) arrays, the layout of DztFile.channels. Integer data are stored as they are
    (they must fit the sample type). Float data are scaled by one factor for all channels so that
    the largest magnitude reaches full scale, then rounded and offset into the unsigned types.
    `created` is stored as wall-clock fields, seconds floored to even; None stores no date.
    """
    _check_write_args(range_ns, traces_per_m, traces_per_s, eps_r, position_ns, antenna)
    stored = _to_stored(_channel_stack(data), bits)
    if not MIN_DT_NS <= range_ns / stored.shape[1] <= MAX_DT_NS:
        raise DataFormatError(
            f"cannot write DZT: range_ns={range_ns:g} over {stored.shape[1]} samples is a sample interval of "
            f"{range_ns / stored.shape[1]:.3g} ns (need {MIN_DT_NS * 1000:g} ps..{MAX_DT_NS:g} ns)"
        )
    header = DztHeader(
        channels=stored.shape[0],
        samples=stored.shape[1],
        bits=bits,
        traces=stored.shape[2],
        range_ns=range_ns,
        position_ns=position_ns,
        traces_per_m=traces_per_m,
        traces_per_s=traces_per_s,
        eps_r=eps_r,
        depth_m=velocity_from_eps(eps_r) * range_ns / 2.0,
        antenna=antenna,
        created=created,
        modified=None,
        data_offset=HEADER_SIZE * stored.shape[0],
        system=None,
    )
    target = Path(path)
    one_header = pack_header(header, file_name=target.stem)
    scans = np.ascontiguousarray(stored.transpose(2, 0, 1))  # (traces, channels, samples)
    write_bytes_atomic(target, one_header * header.channels + scans.tobytes())


def _channel_stack(data: Sequence[NDArray[Any]] | NDArray[Any]) -> NDArray[Any]:
    """The input as one (channels, samples, traces) array, checked for shape and kind."""
    if isinstance(data, np.ndarray) and data.ndim == 2:
        data = [data]
    arrays = [np.asarray(channel) for channel in data]
    if not 1 <= len(arrays) <= WRITE_MAX_CHANNELS:
        raise DataFormatError(
            f"cannot write {len(arrays)} channels to DZT: give 1..{WRITE_MAX_CHANNELS} (samples, traces) "
            "arrays (readgssi reads at most 4 channels)"
        )
    shapes = {a.shape for a in arrays}
    kinds = {a.dtype.kind for a in arrays}
    if len(shapes) != 1 or arrays[0].ndim != 2:
        raise DataFormatError(
            f"cannot write DZT: every channel must be one 2-D (samples, traces) "
            f"array of the same shape, got shapes {sorted(shapes)}"
        )
    if not (kinds <= {"u", "i"} or kinds <= {"f"}):
        raise DataFormatError(
            f"cannot write DZT: samples must be all integer or all float, got dtype kinds {sorted(kinds)}"
        )
    samples, traces = arrays[0].shape
    if not (MIN_SAMPLES <= samples <= WRITE_MAX_SAMPLES and traces >= 1):
        raise DataFormatError(
            f"cannot write DZT: {samples} samples x {traces} traces; need {MIN_SAMPLES}..{WRITE_MAX_SAMPLES} "
            "samples per trace and at least one trace"
        )
    return np.stack(arrays)


def _to_stored(channels: NDArray[Any], bits: int) -> NDArray[Any]:
    """The samples in the file's integer type: floats scaled to full scale, integers range-checked."""
    if bits not in _STORED_DTYPES:
        raise DataFormatError(f"cannot write DZT with bits={bits}: choose 8, 16 or 32")
    stored = _STORED_DTYPES[bits]
    info = np.iinfo(stored)
    if channels.dtype.kind == "f":
        if not np.isfinite(channels).all():
            raise DataFormatError("cannot write DZT: the samples contain NaN or infinity; clean them first")
        peak = float(np.abs(channels).max())
        full_scale = float(2 ** (bits - 1) - 1)
        scale = full_scale / peak if peak > 0.0 else 1.0
        counts = np.rint(channels.astype(np.float64) * scale) + _UNSIGNED_OFFSET[bits]
        return counts.astype(stored)
    low, high = int(channels.min()), int(channels.max())
    if low < info.min or high > info.max:
        raise DataFormatError(
            f"cannot write DZT: integer samples span {low}..{high}, outside the {bits}-bit range "
            f"{info.min}..{info.max}; pass float data to have it scaled, or choose other bits"
        )
    return channels.astype(stored)


def _check_write_args(
    range_ns: float, traces_per_m: float, traces_per_s: float, eps_r: float, position_ns: float, antenna: str
) -> None:
    """Refuse header values that the reader (or readgssi) would reject."""
    problems = []
    if not 0.0 < range_ns <= MAX_RANGE_NS:
        problems.append(f"range_ns={range_ns} (need 0 < range_ns <= {MAX_RANGE_NS:g})")
    if not (traces_per_m == 0.0 or MIN_TRACES_PER_M <= traces_per_m <= MAX_TRACES_PER_M):
        problems.append(f"traces_per_m={traces_per_m} (need 0 or {MIN_TRACES_PER_M:g}..{MAX_TRACES_PER_M:g})")
    if not 0.0 <= traces_per_s <= MAX_TRACES_PER_S:
        problems.append(f"traces_per_s={traces_per_s} (need 0..{MAX_TRACES_PER_S:g})")
    if not MIN_EPS_R <= eps_r <= MAX_EPS_R:  # relative permittivity: 1 (air) .. ~80 (water)
        problems.append(f"eps_r={eps_r} (need {MIN_EPS_R:g} <= eps_r <= {MAX_EPS_R:g})")
    if not (_fits_float32(position_ns) and abs(position_ns) <= range_ns):
        problems.append(f"position_ns={position_ns} (need a finite value within the window)")
    if len(antenna) > 14 or not antenna.isascii():
        problems.append(f"antenna={antenna!r} (need at most 14 ASCII characters)")
    if problems:
        raise DataFormatError("cannot write DZT: " + "; ".join(problems))


def _fits_float32(value: float) -> bool:
    """Whether `value` is finite and within float32 range, as header fields are stored."""
    return math.isfinite(value) and abs(value) <= float(np.finfo(np.float32).max)
