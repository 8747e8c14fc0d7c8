"""A survey line prepared for picking, and the travel-time model of a pipe crossing it.

Every model uses the exact refracted two-way time to the cylinder's specular point with the antenna
height and the Tx–Rx offset (`traveltime.two_way_time`). The antenna's sideways wander off the line's
straight axis is kept (`LineData.lateral_m`): over an oblique pipe it shifts the crossing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage, signal

from gprbot.config import GprConfig
from gprbot.gpr.bscan import BScan, check_bscan, grid_spacing_m
from gprbot.gpr.migration import diffraction_times, resample_uniform
from gprbot.gpr.preprocess import (
    BACKGROUND,
    BACKGROUND_WINDOW_M,
    DEWOW,
    dewow,
    direct_wave_polarity,
    find_time_zero,
    recorded_direct_polarity,
    remove_background,
    remove_gain,
)
from gprbot.gpr.traveltime import two_way_time
from gprbot.gpr.wavelet import ricker

FloatArray = NDArray[np.float64]
FloatLike = float | FloatArray

_IN_LINE = np.array([1.0, 0.0])
_LATERAL_SMOOTH_TRACES = 21
_STRAIGHT_LINE_TOLERANCE_M = 0.05  # as `bscan.along_track_distance`



@dataclass(frozen=True)
class LineData:
    """A preprocessed line on a uniform along-track grid, ready for picking (matched-filtered, no gain)."""

    data: FloatArray  # (nx, ns)
    x_m: FloatArray
    dt_ns: float
    t0_ns: float
    noise: float  # robust standard deviation of the samples
    period_ns: float
    direct_polarity: float  # sign of the direct wave: echoes of this sign come from lower permittivity
    lateral_m: FloatArray  # antenna's offset left of the line's straight axis at each x_m (0: curved line)

    def time_of(self, sample: FloatArray | float) -> FloatArray:
        """Two-way time after transmit (ns) of a (fractional) sample index."""
        return np.asarray(np.asarray(sample) * self.dt_ns - self.t0_ns)



def prepare_line(bscan: BScan, gpr: GprConfig) -> LineData:
    """Dewow, time zero, uniform grid, median background removal, matched filter — and no gain.

    A B-scan that was already preprocessed has its gain undone (a gain ramp shifts peaks).
    """
    check_bscan(bscan)
    raw = remove_gain(bscan)
    dewowed = raw.data if DEWOW in raw.processing else dewow(raw.data, raw.dt_ns, gpr.centre_frequency_mhz)
    t0 = raw.t0_ns
    if not math.isfinite(t0):
        t0 = find_time_zero(dewowed, raw.dt_ns, gpr.tx_rx_offset_m, gpr.antenna_height_m)
    resampled, x = resample_uniform(replace(raw, data=dewowed), grid_spacing_m(raw.along_track_m()))
    window = BACKGROUND_WINDOW_M if float(x[-1] - x[0]) > BACKGROUND_WINDOW_M else None
    cleaned = remove_background(resampled, x, window_m=window, spacing_m=float(x[1] - x[0]))
    d = matched_filter(np.asarray(cleaned, dtype=np.float64), raw.dt_ns, gpr.centre_frequency_mhz)
    noise = float(1.4826 * np.median(np.abs(d - np.median(d)))) or float(np.std(d)) or 1e-12
    period = 1000.0 / gpr.centre_frequency_mhz
    # The direct wave's sign: recorded by preprocess before it removed the background, or read here.
    polarity = recorded_direct_polarity(raw.processing)
    if polarity is None:
        polarity = direct_wave_polarity(dewowed, raw.dt_ns) if BACKGROUND not in raw.processing else 1.0
    return LineData(d, x, raw.dt_ns, t0, noise, period, polarity, lateral_offsets(raw, x))


def lateral_offsets(bscan: BScan, x_m: FloatArray) -> FloatArray:
    """The antenna's offset (m) to the left of the line's straight axis, at along-track coordinates x_m.

    A robot following a line wanders a few mm sideways; over a pipe crossing at angle φ that moves the
    crossing by (offset · cot φ) along the line and bends the hyperbola (measured on the oblique
    scene: per-line radii of a 3 cm pipe scatter 1.4–5.6 cm with the wander, 2.9–3.3 cm without).
    Zero for a line that is not straight (the in-line model does not hold there anyway).
    """
    p = np.asarray(bscan.positions, dtype=np.float64)[:, :2]
    along = bscan.along_track_m()
    centred = p - p.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    direction = vt[0] if float((p[-1] - p[0]) @ vt[0]) >= 0.0 else -vt[0]
    lateral = centred @ np.array([-direction[1], direction[0]])
    if len(p) < _LATERAL_SMOOTH_TRACES or float(np.max(np.abs(lateral))) > _STRAIGHT_LINE_TOLERANCE_M:
        return np.zeros(len(x_m))
    # Pose noise is white from trace to trace, the wander is smooth over tens of centimetres.
    lateral = signal.savgol_filter(lateral, _LATERAL_SMOOTH_TRACES, 2, mode="interp")
    order = np.argsort(along, kind="stable")
    return np.asarray(np.interp(x_m, along[order], lateral[order]))


def matched_filter(data: FloatArray, dt_ns: float, centre_frequency_mhz: float) -> FloatArray:
    """Correlate every trace with the Ricker wavelet: the peak times stay, the white noise drops ~4×.

    A peak picked on three raw samples sees the noise of three samples; after the matched filter it
    sees that of the whole wavelet. The Ricker is symmetric, so correlation moves no peak.
    """
    half = math.ceil(1.5 * 1000.0 / (centre_frequency_mhz * dt_ns))
    kernel = ricker(np.arange(-half, half + 1, dtype=np.float64) * dt_ns, centre_frequency_mhz)
    kernel /= float(np.sum(kernel**2))
    return np.asarray(ndimage.convolve1d(data, kernel, axis=1, mode="constant"))


def cylinder_times(
    x_m: FloatArray, x0: FloatLike, dc: FloatLike, radius: FloatLike, v: float, gpr: GprConfig,
    sin_cross: FloatLike = 1.0,
) -> FloatArray:
    """Two-way times along the line to a pipe crossing it at x0 (centre depth dc, radius, crossing angle).

    `sin_cross` is the sine of the angle between the pipe's axis and the line (1: at right angles).
    The pipe parameters broadcast against x_m (one pipe, or one pipe per pick). The reflection
    comes from the specular point: the point of the pipe's surface nearest to the ground point
    under the antenna (as `traveltime.cylinder_specular_point`).
    """
    x = np.asarray(x_m, dtype=np.float64)
    s = np.clip(np.asarray(sin_cross, dtype=np.float64), 1e-3, 1.0)
    cos = np.sqrt(1.0 - s * s)
    depth = np.asarray(dc, dtype=np.float64)
    dx = x - np.asarray(x0, dtype=np.float64)
    along_axis = dx * cos  # ground point minus centre, projected on the axis direction (cos, s, 0)
    gx, gy, gz = dx - along_axis * cos, -along_axis * s, depth  # from the nearest axis point to the ground point
    dist = np.maximum(np.sqrt(gx * gx + gy * gy + gz * gz), 1e-9)
    shrink = 1.0 - np.asarray(radius, dtype=np.float64) / dist
    point = np.stack(np.broadcast_arrays(x - gx * shrink, -gy * shrink, -gz * shrink), axis=-1)
    mid = np.stack([x, np.zeros_like(x)], axis=-1)
    return two_way_time(mid, point, v, gpr.antenna_height_m, gpr.tx_rx_offset_m, _IN_LINE)


def depth_for_apex_time(t_ns: float, v: float, gpr: GprConfig) -> float:
    """Depth of a point diffractor right below the antenna whose two-way time is t_ns."""
    z = np.linspace(0.0, max(0.05, v * t_ns), 400)
    times = diffraction_times(np.zeros(1), z, v, gpr.antenna_height_m, gpr.tx_rx_offset_m)[0]
    return float(np.interp(t_ns, times, z))
