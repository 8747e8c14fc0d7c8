"""The common result of every GPR file reader (`Radargram`) and the bounds every reader checks."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from gprbot.atomic_files import atomic_open
from gprbot.errors import DataFormatError

# What a real GPR can produce; a header outside these is corrupt (or not a GPR file).
MAX_SAMPLES = 65_536  # per trace: SEG-Y's 16-bit sample count; no GPR records more
MAX_TRACES = 2_000_000  # per line: 2 km at 1 mm spacing
MAX_CELLS = 100_000_000  # traces x samples: 400 MB as float32, the most one read may allocate
MIN_DT_NS, MAX_DT_NS = 1e-4, 100.0  # 0.1 ps (fine FDTD) .. 100 ns (a 5 MHz ice radar)
MAX_WINDOW_NS = 100_000.0  # 100 µs: 15 km of air
MIN_FREQUENCY_MHZ, MAX_FREQUENCY_MHZ = 10.0, 10_000.0
MAX_SEPARATION_M = 100.0
MAX_TEXT_HEADER = 1_000_000  # bytes of a text header (.HD, .rad, .in) worth reading


@dataclass(frozen=True)
class Radargram:
    """One GPR line read from any format: (traces, samples) float32 and what the file states about it.

    `positions_m` are distances along the line (m, per trace) or None when the file has no distance
    calibration; `time_zero_ns` is the transmit instant after sample 0 where the file states it;
    `geo` holds per-trace (latitude °, longitude °, altitude m) from a GPS sidecar, NaN where unknown.
    """

    samples: NDArray[np.float32]
    dt_ns: float
    source_format: str
    positions_m: NDArray[np.float64] | None = None
    time_zero_ns: float | None = None
    frequency_mhz: float | None = None
    antenna_separation_m: float | None = None
    antenna: str = ""
    header: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    geo: NDArray[np.float64] | None = None

    @property
    def traces(self) -> int:
        """Number of traces."""
        return int(self.samples.shape[0])

    @property
    def n_samples(self) -> int:
        """Samples per trace."""
        return int(self.samples.shape[1])

    @property
    def window_ns(self) -> float:
        """The time window: n_samples x dt_ns."""
        return self.n_samples * self.dt_ns

    def spacing_m(self) -> float | None:
        """The mean trace spacing (m), or None without positions or with fewer than two traces."""
        if self.positions_m is None or self.traces < 2:
            return None
        step = float(abs(self.positions_m[-1] - self.positions_m[0])) / (self.traces - 1)
        return step if step > 0 else None


def check_size(source: str, traces: int, samples: int) -> None:
    """DataFormatError unless traces x samples is what a GPR can record and we may allocate."""
    if not 1 <= samples <= MAX_SAMPLES:
        raise DataFormatError(f"{source}: {samples} samples per trace (expected 1..{MAX_SAMPLES}); header corrupt")
    if not 1 <= traces <= MAX_TRACES:
        raise DataFormatError(f"{source}: {traces} traces (expected 1..{MAX_TRACES}); the file is empty or corrupt")
    if traces * samples > MAX_CELLS:
        raise DataFormatError(
            f"{source}: {traces} traces x {samples} samples is more than {MAX_CELLS} values; "
            "split the line into shorter files"
        )


def check_dt(source: str, dt_ns: float, samples: int) -> float:
    """The sample interval if it and the window it gives are plausible, else DataFormatError."""
    if not (math.isfinite(dt_ns) and MIN_DT_NS <= dt_ns <= MAX_DT_NS):
        raise DataFormatError(
            f"{source}: sample interval {dt_ns:g} ns (expected {MIN_DT_NS:g}..{MAX_DT_NS:g} ns); the header is corrupt"
        )
    if dt_ns * samples > MAX_WINDOW_NS:
        raise DataFormatError(f"{source}: window {dt_ns * samples:g} ns exceeds {MAX_WINDOW_NS:g} ns; header corrupt")
    return float(dt_ns)


def plausible_frequency(value: float | None, notes: list[str], what: str) -> float | None:
    """A stated antenna frequency (MHz) if it is 10 MHz..10 GHz; otherwise None and a note."""
    if value is None or value == 0:
        return None
    if math.isfinite(value) and MIN_FREQUENCY_MHZ <= value <= MAX_FREQUENCY_MHZ:
        return float(value)
    notes.append(f"{what} {value:g} MHz is not an antenna frequency (10 MHz..10 GHz); ignored, pass --frequency")
    return None


def plausible_separation(value: float | None, notes: list[str], what: str) -> float | None:
    """A stated Tx–Rx separation (m) if it is 0..100 m; otherwise None and a note."""
    if value is None:
        return None
    if math.isfinite(value) and 0.0 <= value <= MAX_SEPARATION_M:
        return float(value)
    notes.append(f"{what} {value:g} m is not an antenna separation; ignored")
    return None


def uniform_positions(n: int, step: float, start: float = 0.0) -> NDArray[np.float64]:
    """Positions start + i x step for n traces."""
    return start + np.arange(n, dtype=np.float64) * step


def read_text(path: Path, what: str) -> str:
    """A small text header file as str (latin-1, so any byte decodes); DataFormatError if unreadable."""
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_TEXT_HEADER + 1)
    except OSError as exc:
        raise DataFormatError(f"cannot read {what} {path}: {exc.strerror or exc}; check the path") from exc
    if len(raw) > MAX_TEXT_HEADER:
        raise DataFormatError(f"{path}: {what} is larger than {MAX_TEXT_HEADER} bytes; it is not a header file")
    return raw.decode("latin-1")


def read_bytes(path: Path, what: str) -> bytes:
    """A whole data file; DataFormatError naming the path if it cannot be read."""
    try:
        return path.read_bytes()
    except OSError as exc:
        raise DataFormatError(f"cannot read {what} {path}: {exc.strerror or exc}; check the path") from exc


def sibling(path: Path, suffixes: tuple[str, ...]) -> Path | None:
    """The file beside `path` with the same stem and one of `suffixes` (any letter case), if any."""
    wanted = {s.lower() for s in suffixes}
    if path.parent.is_dir():
        for candidate in sorted(path.parent.iterdir()):
            if candidate.stem == path.stem and candidate.suffix.lower() in wanted and candidate.is_file():
                return candidate
    return None


def write_atomically(target: Path, fill: Callable[[BinaryIO], None]) -> None:
    """Write a file through a temp file beside `target`, fsync it, then rename it over `target`."""
    target.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(target) as handle:
        fill(handle)


def integer_counts(samples: NDArray[np.float32], bits: int) -> tuple[NDArray[np.int64], float]:
    """Samples as signed integers of `bits`: kept exactly if integral and in range, else scaled to full scale.

    Returns the counts and the factor they were multiplied by (1.0 when kept exactly).
    """
    data = np.asarray(samples, dtype=np.float64)
    if not np.isfinite(data).all():
        raise DataFormatError("cannot write: the samples contain NaN or infinity; clean them first")
    full = 2 ** (bits - 1) - 1
    peak = float(np.abs(data).max()) if data.size else 0.0
    if np.array_equal(data, np.rint(data)) and data.min(initial=0) >= -full - 1 and data.max(initial=0) <= full:
        return data.astype(np.int64), 1.0
    scale = full / peak if peak > 0 else 1.0
    return np.rint(data * scale).astype(np.int64), scale


def positions_mm(positions: NDArray[np.float64]) -> NDArray[np.int64]:
    """Positions (m) in whole millimetres for 32-bit coordinate fields."""
    mm = np.rint(np.asarray(positions, dtype=np.float64) * 1000.0)
    if not np.isfinite(mm).all() or (mm.size and np.abs(mm).max() >= 2**31):
        raise DataFormatError("cannot write trace positions beyond ±2147 km into 32-bit coordinates")
    return mm.astype(np.int64)
