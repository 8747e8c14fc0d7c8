"""First curves for the picks: the semblance of a B-scan along trial cylinder travel-time curves.

A pipe or bar of radius R with its centre at depth zc is timed as a point diffractor at zc minus 2R/v,
with straight rays from the antennas' footprints plus the air gap: a first guess only (the picks follow
the data, the fits use the refracted model). The coherence is the semblance of the traces along the
curve in a window of half a period around it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

from gprbot.gpr.chain.geometry import cylinder_time
from gprbot.gpr.chain.prepare import PreparedBScan
from gprbot.gpr.traveltime import C_M_PER_NS

FloatArray = NDArray[np.float64]

MAX_LAGS = 24  # traces used on each side of an apex (strided beyond): enough to see the curvature
APERTURE_DEG = 50.0  # in-ground angle from vertical beyond which flanks are not used
MIN_SUPPORT = 7  # traces a curve must cross for its semblance to count in full


@dataclass(frozen=True)
class TravelTable:
    """Two-way times (nv, nk, nz) to a point at depth z_m[j] from an antenna lag_traces[k] grid steps along the line."""

    velocities: FloatArray
    lag_traces: FloatArray
    z_m: FloatArray
    t_ns: FloatArray


def travel_table(prep: PreparedBScan, velocities: FloatArray, z_max_m: float, max_lag_traces: int) -> TravelTable:
    """Travel times for the trial velocities on the line's lags; straight rays scale as 1/v when height is 0."""
    stride = max(1, int(np.ceil(max_lag_traces / MAX_LAGS)))
    lag_idx = np.arange(-max_lag_traces, max_lag_traces + 1, stride)
    lags = np.asarray(lag_idx * prep.dx_m, dtype=np.float64)
    z = np.linspace(0.002, max(z_max_m, 0.02), 120)
    # A first guess only (the picks follow the data, the fits use the refracted model): straight rays
    # from the antennas' footprints, which scale as 1/v, plus the air gap down and up.
    unit = cylinder_time(lags[:, None], 0.0, z[None, :], 0.0, 1.0, 0.0, prep.tx_rx_offset_m)
    v = np.asarray(velocities, dtype=np.float64)[:, None, None]
    t = unit[None, :, :] / v + 2.0 * prep.antenna_height_m / C_M_PER_NS
    return TravelTable(np.asarray(velocities, dtype=np.float64), lag_idx.astype(np.float64), z, t)


def centre_depths(table: TravelTable, apex_t_ns: FloatArray | float, radii: FloatArray) -> FloatArray:
    """Centre depth (..., nv, nr) whose apex time matches each `apex_t_ns` (...) per trial velocity and radius
    (NaN: none)."""
    apex = np.asarray(apex_t_ns, dtype=np.float64)[..., None]
    out = np.full((*apex.shape[:-1], len(table.velocities), len(radii)), np.nan)
    zero = int(np.argmin(np.abs(table.lag_traces)))
    for i, v in enumerate(table.velocities):
        column = table.t_ns[i, zero]
        target = apex + 2.0 * radii / v
        ok = (target >= column[0]) & (target <= column[-1])
        out[..., i, :][ok] = np.interp(target[ok], column, table.z_m)
    return out


def curve_samples(table: TravelTable, zc: FloatArray, radii: FloatArray, t0_ns: float, dt_ns: float) -> FloatArray:
    """Sample positions (nv, nr, nk) of the curve through every lag for each (velocity, radius) pair."""
    pos = np.interp(np.nan_to_num(zc, nan=table.z_m[0]), table.z_m, np.arange(len(table.z_m)))
    j0 = np.clip(pos.astype(np.intp), 0, len(table.z_m) - 2)
    f = (pos - j0)[..., None]
    vi = np.arange(len(table.velocities))[:, None]
    t_lo = table.t_ns[vi, :, j0]  # (nv, nr, nk)
    t_hi = table.t_ns[vi, :, j0 + 1]
    t = t_lo * (1.0 - f) + t_hi * f - (2.0 * radii[None, :] / table.velocities[:, None])[..., None]
    return np.asarray((t + t0_ns) / dt_ns)


def semblance(
    prep: PreparedBScan, column: int | NDArray[np.intp], samples: FloatArray, lags: FloatArray,
    aperture: NDArray[np.bool_], half_window: int,
) -> FloatArray:
    """Semblance (...,) of the traces at column+lag along `samples` (..., nk), within a ±half_window window.

    `column` is one apex column or an array of them broadcasting against samples' leading axes. Lags
    outside the line or the aperture count as absent (not as zeros), so that a hyperbola near the line's
    end is judged on the flank that exists.
    """
    nx, ns = prep.data.shape
    cols = np.asarray(column, dtype=np.intp)[..., None] + lags.astype(np.intp)
    present = aperture & (cols >= 0) & (cols < nx)  # (..., nk)
    centre = np.rint(samples).astype(np.intp)
    first = centre - half_window
    n = (present & (first >= 0) & (first < ns)).sum(axis=-1)  # lags whose window starts inside the record
    # Absent lags read a zero trace and samples outside the record a zero margin, so one gather of the
    # padded copy gives the values (zeros where absent) without a mask the size of the gather: a
    # window wholly outside the record is moved, clamped, to lie wholly in the margin.
    padded = _padded_traces(prep, half_window)
    margin = 2 * half_window + 1
    start = np.minimum(np.maximum(centre, -half_window - 1), ns + half_window) + (margin - half_window)
    row = np.where(present, cols, nx)
    # Each lag's window is one row of a sliding-window view: the gather copies whole windows, and no
    # index array the size of the gather is built. Single precision: half the memory traffic.
    windows = sliding_window_view(padded.ravel(), 2 * half_window + 1)
    vals = windows[row * padded.shape[1] + start]  # (..., nk, nw); (np.take would copy the whole view)
    stacked = (_sum_over_lags(vals) ** 2).sum(axis=-1)
    energy = (vals * vals).sum(axis=(-2, -1))
    # A curve seen on a handful of traces only (it leaves the record) is no evidence of its shape.
    support = np.minimum(1.0, n / MIN_SUPPORT)
    return np.asarray(support * stacked / np.maximum(np.maximum(n, 1) * energy, 1e-30))


def _sum_over_lags(vals: NDArray[np.float32]) -> NDArray[np.float32]:
    """`vals.sum(axis=-2)`, the same floats four times faster.

    NumPy sums over a non-last axis in index order, one lag after another, and so does einsum; einsum
    just walks the small last axis in one loop instead of one call each. With one sample in the window
    the lags are the last contiguous axis, which `sum` adds pairwise: that case keeps `sum`.
    """
    if vals.shape[-1] < 2:
        return np.asarray(vals.sum(axis=-2))
    return np.asarray(np.einsum("...kw->...w", vals))


def _padded_traces(prep: PreparedBScan, half_window: int) -> NDArray[np.float32]:
    """The single-precision traces with a zero margin of 2·half_window+1 samples each side and a zero trace after."""
    nx, ns = prep.data.shape
    margin = 2 * half_window + 1
    padded = np.zeros((nx + 1, ns + 2 * margin), dtype=np.float32)
    padded[:nx, margin : margin + ns] = prep.data32
    return padded


def aperture_mask(table: TravelTable, zc: FloatArray, dx_m: float, min_lags: int = 2) -> NDArray[np.bool_]:
    """Lags (..., nk) within the aperture angle of a centre at depth zc (always the nearest min_lags)."""
    reach = np.tan(np.radians(APERTURE_DEG)) * np.nan_to_num(zc, nan=0.0)[..., None]
    horiz = np.abs(table.lag_traces) * dx_m
    nearest = np.abs(table.lag_traces) <= min_lags * max(1.0, table.lag_traces[1] - table.lag_traces[0])
    return np.asarray((horiz <= reach) | nearest)
