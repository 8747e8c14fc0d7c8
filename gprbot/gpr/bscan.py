"""B-scans and the results of interpreting them: BScan, Detection, CrossSection.

A B-scan is a line of traces (n_traces, n_samples) with the antenna midpoint of every trace in the
site frame. Along-track coordinates (metres from the first trace) are what every 2D product —
migrated image, cross-section mask, detections — is indexed by.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from gprbot.errors import InterpretationError
from gprbot.gpr.wavelet import ricker

FloatArray = NDArray[np.float64]

# A line is "straight" when no trace strays further than this from the line's principal axis;
# along-track distance is then the projection on that axis, which does not accumulate pose jitter.
_STRAIGHT_LINE_TOLERANCE_M = 0.05
_SMOOTH_TRACES = 21
MIN_TRACES = 8
MIN_SAMPLES = 16
# The uniform along-track grid: never finer than 1 cm (a robot triggering at 100 Hz at 0.1 m/s records
# traces 1 mm apart, well below the pose noise), never coarser than 5 cm (a quarter wavelength at 400 MHz).
GRID_SPACING_MIN_M = 0.01
GRID_SPACING_MAX_M = 0.05


@dataclass(frozen=True)
class BScan:
    """One line of GPR traces with the position of every trace.

    `t0_ns` is the time of the transmit instant counted from sample 0 (so sample k lies at
    k * dt_ns - t0_ns after transmit); NaN means unknown: `preprocess` then estimates it from the
    direct wave. `processing` lists the preprocessing steps already applied ("dewow", "background",
    "gain:<power>:<cap>"), so that no step runs twice and picking can undo the gain.
    """

    data: NDArray[np.float32]
    dt_ns: float
    t0_ns: float
    positions: FloatArray
    times: FloatArray
    processing: tuple[str, ...] = ()
    position_std_m: FloatArray | None = None  # per trace, 1σ of its horizontal position (pose filter); None: unknown

    def along_track_m(self) -> FloatArray:
        """Horizontal distance of every trace from the first one, along the line (m); read-only.

        Made once per B-scan (its positions never change): every stage asks for it, and its smoothing fit
        cost a few milliseconds a call (five calls a line in the interpretation chain and MigrationNet).
        """
        cached: FloatArray | None = self.__dict__.get("_along_track_m")
        if cached is None:
            cached = along_track_distance(self.positions)
            cached.setflags(write=False)
            object.__setattr__(self, "_along_track_m", cached)  # a cache, not a field: replace() makes a new one
        return cached

    def position_at(self, along_m: FloatArray | float) -> FloatArray:
        """Site-frame antenna midpoint (..., 3) at along-track coordinate(s), interpolated."""
        along = self.along_track_m()
        order = np.argsort(along, kind="stable")
        a = np.asarray(along_m, dtype=np.float64)
        cols = [np.interp(a, along[order], self.positions[order, k]) for k in range(3)]
        return np.stack(cols, axis=-1)


@dataclass(frozen=True)
class Detection:
    """A pipe crossing the line: along-track x, depth of the pipe's centre (m, positive), radius, score."""

    x_m: float
    depth_m: float
    radius_m: float
    score: float
    radius_supported: bool = True  # False: the data do not measure it (the chain's `reported_radius`)
    radius_from_mask: bool = False  # the radius is the half-height of MigrationNet's blob (the chain's `sizing`)


@dataclass(frozen=True)
class CrossSection:
    """The interpretation of one B-scan: filled pipe mask on an (z, x) grid, image, detections."""

    mask: NDArray[np.bool_]
    x_m: FloatArray
    z_m: FloatArray
    image: NDArray[np.float32]
    detections: tuple[Detection, ...]
    velocity_m_per_ns: float
    velocity_estimated: bool
    rebars: tuple[Detection, ...] = ()  # reinforcement bars found on the line (not pipes, not in the mask)


def along_track_distance(positions: FloatArray) -> FloatArray:
    """Along-track coordinate of each position (n, 3): projection on the line's axis if straight.

    Cumulative distance along a jittery pose track overestimates the length (every perpendicular
    wiggle adds), so a straight line is measured by projection (smoothed over 21 traces); a curved
    one by the cumulative distance of its path smoothed over 5 traces.
    """
    p = np.asarray(positions, dtype=np.float64)[:, :2]
    if len(p) < 2:
        return np.zeros(len(p))
    centred = p - p.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    axis = vt[0]
    along = (p - p[0]) @ axis
    across = centred @ vt[1] if vt.shape[0] > 1 else np.zeros(len(p))
    if np.max(np.abs(across)) <= _STRAIGHT_LINE_TOLERANCE_M:
        if along[-1] < along[0]:
            along = -along
        if len(along) > _SMOOTH_TRACES:
            # Pose noise is white from trace to trace, the robot's motion is not: a quadratic
            # Savitzky–Golay fit over ~1 s keeps the motion and cuts the jitter ~3×.
            along = signal.savgol_filter(along, _SMOOTH_TRACES, 2, mode="interp")
        return np.asarray(along - along[0])
    kernel = np.ones(5) / 5.0
    smooth = np.stack([np.convolve(np.pad(p[:, k], 2, mode="edge"), kernel, "valid") for k in range(2)], 1)
    steps = np.hypot(*np.diff(smooth, axis=0).T)
    return np.concatenate([[0.0], np.cumsum(steps)])


def grid_spacing_m(along_m: FloatArray) -> float:
    """Spacing of the uniform along-track grid for a line: its mean trace spacing, clamped to 1–5 cm."""
    along = np.asarray(along_m, dtype=np.float64)
    mean_step = float(np.ptp(along)) / max(len(along) - 1, 1)
    return float(np.clip(mean_step, GRID_SPACING_MIN_M, GRID_SPACING_MAX_M))


def binned_sums(rows: NDArray[np.floating], index: NDArray[np.intp], n_bins: int) -> FloatArray:
    """Sums (n_bins, ...) in double precision of the rows in each bin (`index`: each row's bin): np.add.at's floats.

    np.add.at adds row after row into its bin, unbuffered and slowly; here step k adds the k-th row of
    every bin at once (rows in their order within a bin), so each bin gets the same additions from zero
    in the same order.
    """
    out = np.zeros((n_bins, *np.shape(rows)[1:]))
    order = np.argsort(index, kind="stable")
    in_order = index[order]
    starts = np.flatnonzero(np.r_[True, in_order[1:] != in_order[:-1]])
    rank = np.arange(len(index)) - np.repeat(starts, np.diff(np.r_[starts, len(index)]))  # place in its bin
    for k in range(int(rank.max(initial=-1)) + 1):
        rows_k = order[rank == k]
        out[index[rows_k]] += rows[rows_k]
    return out


def check_bscan(bscan: BScan) -> None:
    """Raise InterpretationError if a B-scan cannot be interpreted (empty, too short, non-finite)."""
    checked_along_track(bscan)


def checked_along_track(bscan: BScan) -> FloatArray:
    """`check_bscan`'s checks, and the traces' along-track coordinates they measured the line with."""
    data = np.asarray(bscan.data)
    if data.ndim != 2 or data.size == 0:
        raise InterpretationError(
            f"B-scan is empty (data shape {data.shape}); record a line of at least {MIN_TRACES} traces"
        )
    n_traces, n_samples = data.shape
    if n_traces < MIN_TRACES:
        raise InterpretationError(
            f"B-scan has only {n_traces} traces; at least {MIN_TRACES} are needed — survey a longer line"
        )
    if n_samples < MIN_SAMPLES:
        raise InterpretationError(
            f"B-scan traces have only {n_samples} samples; at least {MIN_SAMPLES} are needed"
        )
    if np.asarray(bscan.positions).shape != (n_traces, 3):
        raise InterpretationError(
            f"B-scan positions have shape {np.asarray(bscan.positions).shape}, expected ({n_traces}, 3)"
        )
    if not (bscan.dt_ns > 0 and math.isfinite(bscan.dt_ns)):
        raise InterpretationError(f"B-scan sample interval dt_ns={bscan.dt_ns} must be a positive number")
    if not np.all(np.isfinite(data)):
        raise InterpretationError("B-scan contains NaN or infinite samples; check the acquisition")
    along = bscan.along_track_m()
    if float(np.ptp(along)) <= 0.0:
        raise InterpretationError("B-scan traces all lie at one position; the robot did not move along the line")
    return along


def bscan_from_dzt(dzt: Any, channel: int = 0) -> BScan:
    """A BScan from a DZT file (anything with `.header` and `.as_float(channel)`, see gpr.dzt).

    Trace positions run along x at 1 / traces_per_m; time zero comes from the header's
    position_ns when it is set (> 0), else it is left unknown (NaN) for `preprocess` to estimate.
    """
    header = dzt.header
    data = np.asarray(dzt.as_float(channel), dtype=np.float32)
    traces_per_m = float(getattr(header, "traces_per_m", 0.0) or 0.0)
    if traces_per_m <= 0.0:
        raise InterpretationError(
            "DZT header has no distance calibration (traces_per_m = 0, a time-based survey); "
            "give the trace spacing explicitly"
        )
    n = data.shape[0]
    positions = np.zeros((n, 3))
    positions[:, 0] = np.arange(n) / traces_per_m
    position_ns = float(getattr(header, "position_ns", 0.0) or 0.0)
    t0 = position_ns if position_ns > 0.0 else math.nan
    return BScan(data=data, dt_ns=float(header.dt_ns), t0_ns=t0, positions=positions, times=np.zeros(n))


@dataclass(frozen=True)
class SyntheticTarget:
    """A pipe crossing a synthetic line at right angles: centre x, centre depth, radius, amplitude.

    `inner_echo` is the relative amplitude of an air-filled pipe's inner-bottom echo (4R/c later).
    """

    x_m: float
    depth_m: float
    radius_m: float
    amplitude: float = 1.0
    inner_echo: float = 0.0


def synthetic_bscan(
    targets: tuple[SyntheticTarget, ...] | list[SyntheticTarget],
    *,
    v_m_per_ns: float,
    centre_frequency_mhz: float,
    n_traces: int,
    spacing_m: float,
    samples: int,
    dt_ns: float,
    t0_ns: float,
    antenna_height_m: float,
    tx_rx_offset_m: float,
    noise: float = 0.0,
    direct_wave: float = 0.0,
    flat_depths_m: tuple[float, ...] = (),
    flat_amplitude: float = 0.5,
    footprint_power: float = 0.0,
    rng: np.random.Generator | None = None,
) -> BScan:
    """A B-scan of cylinders and flat reflectors from the refracted travel times (tests, benchmarks).

    Independent of gprbot.sim: reflections from each cylinder's specular point, a Ricker wavelet
    centred on the arrival time, 1/r spreading, an antenna footprint cos(θ)^footprint_power, optional
    direct wave at offset / c and white noise.
    """
    from gprbot.gpr.traveltime import C_M_PER_NS, cylinder_specular_point, two_way_time

    x = np.arange(n_traces) * spacing_m
    mid = np.stack([x, np.zeros(n_traces)], axis=1)
    t = np.arange(samples) * dt_ns - t0_ns
    data = np.zeros((n_traces, samples))
    offset_dir = np.array([1.0, 0.0])

    def add(arrival: FloatArray, amplitude: FloatArray) -> None:
        data[:] += amplitude[:, None] * ricker(t[None, :] - arrival[:, None], centre_frequency_mhz)

    for tg in targets:
        a, b = np.array([tg.x_m, -1.0, -tg.depth_m]), np.array([tg.x_m, 1.0, -tg.depth_m])
        point, dist = cylinder_specular_point(mid, a, b, tg.radius_m)
        arrival = two_way_time(mid, point, v_m_per_ns, antenna_height_m, tx_rx_offset_m, offset_dir)
        r = np.maximum(dist - tg.radius_m, 1e-3)
        cos_theta = tg.depth_m / np.maximum(dist, 1e-9)
        amplitude = tg.amplitude * (tg.depth_m - tg.radius_m) / r * cos_theta**footprint_power
        add(arrival, amplitude)
        if tg.inner_echo:
            add(arrival + 4.0 * tg.radius_m / C_M_PER_NS, tg.inner_echo * amplitude)
    for depth in flat_depths_m:
        below = np.concatenate([mid, np.full((n_traces, 1), -depth)], axis=1)
        add(two_way_time(mid, below, v_m_per_ns, antenna_height_m, tx_rx_offset_m, offset_dir),
            np.full(n_traces, flat_amplitude))
    if direct_wave:
        add(np.full(n_traces, tx_rx_offset_m / C_M_PER_NS), np.full(n_traces, direct_wave))
    if noise:
        data += (rng or np.random.default_rng(0)).normal(0.0, noise, data.shape)
    positions = np.zeros((n_traces, 3))
    positions[:, 0] = x
    return BScan(data.astype(np.float32), dt_ns, t0_ns, positions, np.zeros(n_traces))
