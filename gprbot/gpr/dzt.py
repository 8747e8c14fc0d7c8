"""Read and write GSSI DZT radar files (8/16-bit unsigned, 32-bit signed samples, 1..N channels).

A file is one 1024-byte header per channel (see `dzt_header`), then scans: each scan holds one
trace of every channel in turn (channel 0's samples, then channel 1's, ...). Files we write are
read back by readgssi with the same header values and samples (tests/test_dzt.py checks this).
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import DataFormatError
from gprbot.gpr.dzt_header import (
    HEADER_SIZE,
    MAX_RANGE_NS,
    DztHeader,
    format_info,
    header_info,
    pack_header,
    parse_header,
)
from gprbot.gpr.traveltime import velocity_from_eps

__all__ = ["DztFile", "DztHeader", "format_info", "header_info", "parse_dzt", "read_dzt", "write_dzt"]

_STORED_DTYPES: dict[int, np.dtype[Any]] = {8: np.dtype("<u1"), 16: np.dtype("<u2"), 32: np.dtype("<i4")}
_NATIVE_DTYPES: dict[int, type[np.integer[Any]]] = {8: np.uint8, 16: np.uint16, 32: np.int32}
_UNSIGNED_OFFSET = {8: 128, 16: 32768, 32: 0}  # the spec's binary offset of the unsigned formats
WRITE_MAX_CHANNELS = 4  # readgssi keeps per-channel lists of length 4 and fails beyond
MARKER_SAMPLES = 2  # GSSI units store a trace counter and a mark word in samples 0 and 1


@dataclass(frozen=True)
class DztFile:
    """A DZT file's header and samples: one read-only (samples, traces) array per channel."""

    header: DztHeader
    channels: list[NDArray[Any]]  # dtype as stored: uint8, uint16 or int32
    dropped_bytes: int = 0  # bytes of a trailing partial scan dropped by allow_partial=True

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


def read_dzt(path: str | Path, *, allow_partial: bool = False) -> DztFile:
    """Read a DZT file; DataFormatError (saying what is wrong and what to do) if it is not sound.

    A file whose data end in a partial scan (a recording cut by power loss) is refused unless
    `allow_partial=True`, which drops the partial scan and records its size in `dropped_bytes`.
    """
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise DataFormatError(f"cannot read DZT file {path}: {exc.strerror or exc}; check the path") from exc
    return parse_dzt(raw, source=str(path), allow_partial=allow_partial)


def parse_dzt(raw: bytes, *, source: str = "<bytes>", allow_partial: bool = False) -> DztFile:
    """Parse the bytes of a whole DZT file (see read_dzt); `source` names it in error messages."""
    header, leftover = parse_header(raw, source)
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
    return DztFile(header=header, channels=channels, dropped_bytes=leftover)


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
    _write_atomically(target, one_header * header.channels + scans.tobytes())


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
    if not (1 <= samples <= 32767 and traces >= 1):
        raise DataFormatError(
            f"cannot write DZT: {samples} samples x {traces} traces; need 1..32767 "
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
    for name, value in (("traces_per_m", traces_per_m), ("traces_per_s", traces_per_s)):
        if not (_fits_float32(value) and value >= 0.0):
            problems.append(f"{name}={value} (need a finite value >= 0)")
    if not 1.0 <= eps_r <= 1000.0:  # relative permittivity: 1 (air) .. ~80 (water)
        problems.append(f"eps_r={eps_r} (need 1 <= eps_r <= 1000)")
    if not _fits_float32(position_ns):
        problems.append(f"position_ns={position_ns} (need a finite value)")
    if len(antenna) > 14 or not antenna.isascii():
        problems.append(f"antenna={antenna!r} (need at most 14 ASCII characters)")
    if problems:
        raise DataFormatError("cannot write DZT: " + "; ".join(problems))


def _fits_float32(value: float) -> bool:
    """Whether `value` is finite and within float32 range, as header fields are stored."""
    return math.isfinite(value) and abs(value) <= float(np.finfo(np.float32).max)


def _write_atomically(target: Path, payload: bytes) -> None:
    """Write `payload` to a temp file beside `target`, fsync it, then rename it over `target`."""
    fd, temp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as temp:
            temp.write(payload)
            temp.flush()
            os.fsync(temp.fileno())
        os.replace(temp_name, target)
    except BaseException:
        Path(temp_name).unlink(missing_ok=True)
        raise
