"""B-scan preprocessing: dewow, time zero, background removal and gain (vectorised numpy).

Order matters: dewow first (the wow is a slow, trace-varying drift that would leak into the
background estimate), time zero from the dewowed mean trace, background removal before gain.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from gprbot.config import GprConfig
from gprbot.errors import InterpretationError
from gprbot.gpr.bscan import BScan, binned_sums, check_bscan, grid_spacing_m
from gprbot.gpr.traveltime import C_M_PER_NS

Float32Array = NDArray[np.float32]
FloatArray = NDArray[np.float64]

# The direct wave is looked for in the first part of the window only (reflections come later).
_DIRECT_WAVE_SEARCH_FRACTION = 0.4
_FIRST_BREAK_FRACTION = 0.15
BACKGROUND_WINDOW_M = 3.0
MAX_GAIN = 50.0
DEWOW, BACKGROUND, GAIN, DIRECT = "dewow", "background", "gain", "direct"


def dewow(data: NDArray[np.floating], dt_ns: float, centre_frequency_mhz: float) -> Float32Array:
    """Remove the low-frequency 'wow' and DC: subtract a running mean over one wavelet period."""
    period_samples = 1000.0 / (centre_frequency_mhz * dt_ns)
    width = max(3, round(period_samples) | 1)
    x = np.asarray(data, dtype=np.float32)
    return np.asarray(x - ndimage.uniform_filter1d(x, width, axis=1, mode="nearest"), dtype=np.float32)


def _parabolic_peak(y: FloatArray, i: int) -> float:
    """Sub-sample position of the extremum of y at index i (three-point parabola)."""
    if i <= 0 or i >= len(y) - 1:
        return float(i)
    a, b, c = y[i - 1], y[i], y[i + 1]
    denom = a - 2.0 * b + c
    return float(i) if denom == 0 else float(i + 0.5 * (a - c) / denom)


def direct_wave_peak_ns(data: NDArray[np.floating], dt_ns: float) -> float:
    """Time (ns from sample 0) of the main peak of the direct wave in the line's mean trace.

    The first break is where the mean trace first exceeds a fraction of its early maximum; the
    main peak is the largest |amplitude| within one wavelet of it. The mean over traces keeps the
    direct wave (identical in every trace) and averages reflections away.
    """
    mean = np.asarray(data, dtype=np.float64).mean(axis=0)
    n_search = max(4, int(len(mean) * _DIRECT_WAVE_SEARCH_FRACTION))
    early = np.abs(mean[:n_search])
    peak = float(early.max())
    if peak <= 0.0 or not math.isfinite(peak):
        raise InterpretationError("no direct wave found (the traces are flat); check the antenna and gain")
    first_break = int(np.argmax(early >= _FIRST_BREAK_FRACTION * peak))
    end = min(n_search, first_break + max(3, n_search // 4))
    i = first_break + int(np.argmax(early[first_break:end]))
    return _parabolic_peak(np.abs(mean), i) * dt_ns


def direct_wave_polarity(data: NDArray[np.floating], dt_ns: float) -> float:
    """Sign (+1 or -1) of the direct wave's main peak in the line's mean trace."""
    mean = np.asarray(data, dtype=np.float64).mean(axis=0)
    i = round(direct_wave_peak_ns(data, dt_ns) / dt_ns)
    return 1.0 if mean[min(max(i, 0), len(mean) - 1)] >= 0 else -1.0


def recorded_direct_polarity(processing: tuple[str, ...]) -> float | None:
    """The direct wave's sign recorded by `preprocess` before it removed the background, if any."""
    for step in processing:
        if step.startswith(DIRECT + ":"):
            return float(step.split(":")[1])
    return None


def find_time_zero(
    data: NDArray[np.floating], dt_ns: float, tx_rx_offset_m: float = 0.0, antenna_height_m: float = 0.0
) -> float:
    """Time zero (transmit instant, ns from sample 0) from the direct wave's main peak.

    The direct wave travels Tx → Rx through the air in offset / c. Defining time zero from the
    main peak (not the first break) makes it consistent with reflection times picked at their main
    peaks: the wavelet's own delay cancels. The surface reflection (2h above the surface) merges
    with the direct wave for antennas a few cm up, so the delay used is that of their midpoint.
    """
    path = 0.5 * (tx_rx_offset_m + math.hypot(tx_rx_offset_m, 2.0 * antenna_height_m))
    return direct_wave_peak_ns(data, dt_ns) - path / C_M_PER_NS


def _bin_traces(along_m: FloatArray, spacing_m: float) -> tuple[NDArray[np.intp], int]:
    """Index of each trace's along-track bin (compacted to occupied bins) and the number of bins."""
    raw = np.floor((along_m - along_m.min()) / spacing_m).astype(np.intp)
    occupied, index = np.unique(raw, return_inverse=True)
    return index.astype(np.intp), len(occupied)


def remove_background(
    data: NDArray[np.floating],
    along_m: FloatArray | None = None,
    *,
    window_m: float | None = None,
    spacing_m: float = 0.01,
) -> Float32Array:
    """Subtract the median trace (whole line, or a running median over window_m of line).

    Traces are first averaged per along-track bin so that a robot standing still does not weigh
    its spot more. The median (not the mean) keeps a rebar mesh's hyperbolas and pipes' apices out
    of the background, while anything flat along the line (direct wave, parallel rebar, slab
    bottom) is removed.
    """
    x = np.asarray(data, dtype=np.float32)
    along = np.arange(len(x), dtype=np.float64) * spacing_m if along_m is None else np.asarray(along_m)
    index, n_bins = _bin_traces(along, spacing_m)
    sums = binned_sums(x, index, n_bins)
    bins = sums / np.bincount(index, minlength=n_bins)[:, None]
    window_bins = n_bins if window_m is None else max(3, round(window_m / spacing_m))
    if window_bins >= n_bins:
        background = np.broadcast_to(np.median(bins, axis=0), bins.shape)
    else:
        background = _running_median(bins, window_bins)
    return np.asarray(x - background[index], dtype=np.float32)


def _running_median(rows: FloatArray, window: int) -> FloatArray:
    """Median over `window` rows around each row, computed every window/8 rows and interpolated.

    The background drifts over metres, not centimetres: a coarse running median is as good as a
    per-row one and ~8× cheaper (a full rank filter costs seconds on a 20 m line).
    """
    n = len(rows)
    step = max(1, window // 8)
    centres = np.unique(np.append(np.arange(0, n, step), n - 1))
    half = window // 2
    medians = np.stack([np.median(rows[max(0, c - half) : min(n, c + half + 1)], axis=0) for c in centres])
    at = np.arange(n)
    hi = np.clip(np.searchsorted(centres, at), 1, len(centres) - 1)
    lo = hi - 1
    w = ((at - centres[lo]) / np.maximum(centres[hi] - centres[lo], 1))[:, None]
    return np.asarray(medians[lo] * (1.0 - w) + medians[hi] * w)


def gain_curve(n_samples: int, dt_ns: float, t0_ns: float, *, power: float, max_gain: float) -> FloatArray:
    """Power-of-time gain ((t - t0) / t_ref)^power, 1 before t_ref and capped at max_gain."""
    t = np.arange(n_samples) * dt_ns - t0_ns
    t_ref = 1.0  # ns: gain starts one nanosecond after transmit
    return np.asarray(np.clip((np.maximum(t, t_ref) / t_ref) ** power, 1.0, max_gain))


def apply_gain(
    data: NDArray[np.floating], dt_ns: float, t0_ns: float, *, power: float = 1.0, max_gain: float = 50.0
) -> Float32Array:
    """Multiply every trace by the power-of-time gain (compensates geometric spreading)."""
    g = gain_curve(np.asarray(data).shape[1], dt_ns, t0_ns, power=power, max_gain=max_gain)
    return np.asarray(np.asarray(data, dtype=np.float32) * g[None, :].astype(np.float32), dtype=np.float32)


def preprocess(
    bscan: BScan,
    gpr: GprConfig,
    *,
    background_window_m: float | None = BACKGROUND_WINDOW_M,
    gain_power: float = 1.0,
    gain: bool = True,
) -> BScan:
    """Dewow, time zero (estimated only if the B-scan's t0 is NaN), background removal, gain.

    Steps already listed in `bscan.processing` are skipped, so preprocessing twice is harmless.
    """
    check_bscan(bscan)
    done = bscan.processing
    data = np.asarray(bscan.data, dtype=np.float32)
    steps: list[str] = list(done)
    if DEWOW not in done:
        data = dewow(data, bscan.dt_ns, gpr.centre_frequency_mhz)
        steps.append(DEWOW)
    t0 = bscan.t0_ns
    if not math.isfinite(t0):
        t0 = find_time_zero(data, bscan.dt_ns, gpr.tx_rx_offset_m, gpr.antenna_height_m)
    if BACKGROUND not in done:
        steps.append(f"{DIRECT}:{direct_wave_polarity(data, bscan.dt_ns):+.0f}")
        along = bscan.along_track_m()
        spacing = grid_spacing_m(along)
        length = float(np.ptp(along))
        window = None if background_window_m is None or background_window_m >= length else background_window_m
        data = remove_background(data, along, window_m=window, spacing_m=spacing)
        steps.append(BACKGROUND)
    if gain and applied_gain(done) is None:
        data = apply_gain(data, bscan.dt_ns, t0, power=gain_power, max_gain=MAX_GAIN)
        steps.append(f"{GAIN}:{gain_power}:{MAX_GAIN}")
    return replace(bscan, data=data, t0_ns=float(t0), processing=tuple(steps))


def applied_gain(processing: tuple[str, ...]) -> tuple[float, float] | None:
    """(power, cap) of the gain recorded in a B-scan's processing steps, if one was applied."""
    for step in processing:
        if step.startswith(GAIN + ":"):
            _, power, cap = step.split(":")
            return float(power), float(cap)
    return None


def remove_gain(bscan: BScan) -> BScan:
    """Undo a recorded gain (picking wants the true waveform: a gain ramp shifts peaks)."""
    recorded = applied_gain(bscan.processing)
    if recorded is None:
        return bscan
    g = gain_curve(bscan.data.shape[1], bscan.dt_ns, bscan.t0_ns, power=recorded[0], max_gain=recorded[1])
    steps = tuple(s for s in bscan.processing if not s.startswith(GAIN + ":"))
    return replace(bscan, data=np.asarray(bscan.data / g[None, :], dtype=np.float32), processing=steps)
