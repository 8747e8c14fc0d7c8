"""Measurements shared by both B-scans: preprocessing, correlation, envelope picks, wavelets, predicted times.

Every B-scan is (traces, samples) on the FDTD's time axis: sample k at k·dt, the transmit instant (the
source's peak) at `source_peak_ns`. Times are in ns, positive shifts mean "ours later than the FDTD".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import hilbert

from gprbot.gpr.traveltime import C_M_PER_NS, cylinder_specular_point, two_way_time

FloatArray = NDArray[np.float64]
ANGLES_DEG = (30.0, 45.0)


def preprocess(bscan: FloatArray) -> FloatArray:
    """Remove the mean trace and scale to unit rms."""
    b = bscan - bscan.mean(axis=0, keepdims=True)
    rms = float(np.sqrt(np.mean(b * b)))
    return b / rms if rms > 0 else b


def ncc(a: FloatArray, b: FloatArray) -> float:
    """Normalised cross-correlation at zero lag (1 for identical shapes, -1 for opposite ones)."""
    den = math.sqrt(float(np.sum(a * a)) * float(np.sum(b * b)))
    return float(np.sum(a * b)) / den if den > 0 else math.nan


def shift_samples(b: FloatArray, lag: int) -> FloatArray:
    """b delayed by `lag` samples along the last axis (negative: advanced), zero-filled."""
    out = np.zeros_like(b)
    if lag >= 0:
        out[..., lag:] = b[..., : b.shape[-1] - lag]
    else:
        out[..., :lag] = b[..., -lag:]
    return out


def best_shift(ours: FloatArray, fdtd: FloatArray, max_lag: int) -> tuple[int, float]:
    """(lag in samples, ncc) of the single global time shift of `ours` that best matches `fdtd`."""
    best = (0, -math.inf)
    for lag in range(-max_lag, max_lag + 1):
        c = ncc(shift_samples(ours, -lag), fdtd)  # ours advanced by `lag`: lag > 0 means ours was late
        if c > best[1]:
            best = (lag, c)
    return best


def envelope(bscan: FloatArray) -> FloatArray:
    """Instantaneous amplitude along time (Hilbert transform)."""
    return np.abs(hilbert(bscan, axis=-1))


def pick(env_trace: FloatArray, t0_ns: float, half_ns: float, dt_ns: float) -> tuple[float, float]:
    """(time, value) of the envelope peak within t0 ± half nearest t0 (parabolic sub-sample); NaN outside the trace."""
    lo, hi = max(0, int((t0_ns - half_ns) / dt_ns)), min(len(env_trace) - 1, int((t0_ns + half_ns) / dt_ns) + 1)
    if hi - lo < 2:
        return math.nan, math.nan
    seg = env_trace[lo:hi]
    peaks = [k for k in range(1, len(seg) - 1) if seg[k - 1] < seg[k] >= seg[k + 1] and seg[k] >= 0.5 * seg.max()]
    # the local maximum nearest the prediction: a later, stronger crossing of flanks is not the apex
    k = lo + (min(peaks, key=lambda q: abs(lo + q - t0_ns / dt_ns)) if peaks else int(np.argmax(seg)))
    if 0 < k < len(env_trace) - 1:
        y0, y1, y2 = env_trace[k - 1], env_trace[k], env_trace[k + 1]
        den = y0 - 2 * y1 + y2
        frac = float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5)) if den < 0 else 0.0  # only at a true maximum
        return (k + frac) * dt_ns, float(y1)
    return k * dt_ns, float(env_trace[k])


@dataclass(frozen=True)
class Reflector:
    """A truth target: kind ("pipe"/"rebar"), fill, centre x, centre depth, radius."""

    kind: str
    fill: str
    x_m: float
    depth_m: float
    radius_m: float


def reflectors(truth: dict[str, Any]) -> list[Reflector]:
    """The truth's pipes then rebars."""
    out = [Reflector("pipe", p["fill"], p["x_m"], p["depth_m"], p["radius_m"]) for p in truth["pipes"]]
    return out + [Reflector("rebar", "metal", b["x_m"], b["depth_m"], b["radius_m"]) for b in truth["rebars"]]


def predicted_ns(truth: dict[str, Any], x_m: float, r: Reflector) -> float:
    """Refracted two-way time from the antenna midpoint at x to the cylinder's specular point, on the sample axis."""
    ant = truth["antenna"]
    mid = np.array([[x_m, 0.0]])
    a, b = np.array([r.x_m, -1.0, -r.depth_m]), np.array([r.x_m, 1.0, -r.depth_m])
    point, _ = cylinder_specular_point(mid, a, b, r.radius_m)
    v, h, off = truth["velocity_m_per_ns"], ant["height_m"], ant["tx_rx_offset_m"]
    t = two_way_time(mid, point, v, h, off, np.array([1.0, 0.0]))
    return float(t[0]) + float(truth["source_peak_ns"])


def direct_window_ns(truth: dict[str, Any]) -> float:
    """End of the direct-wave window: the surface echo's time plus 1.5 periods."""
    ant = truth["antenna"]
    surface = 2.0 * math.hypot(ant["height_m"], ant["tx_rx_offset_m"] / 2.0) / C_M_PER_NS
    return float(truth["source_peak_ns"]) + surface + 1.5e3 / truth["frequency_mhz"]


def dominant_mhz(signal: FloatArray, dt_ns: float) -> float:
    """Peak of the amplitude spectrum of a windowed signal (Hann taper, 8× zero padding)."""
    s = signal * np.hanning(len(signal))
    n = 8 * len(s)
    spectrum = np.abs(np.fft.rfft(s, n))
    return float(np.fft.rfftfreq(n, dt_ns)[int(np.argmax(spectrum))] * 1e3)


def wavelet_corr(a: FloatArray, b: FloatArray, max_lag: int) -> tuple[float, int]:
    """(signed ncc at the lag of largest |ncc|, that lag in samples, positive: b later) of two short signals."""
    best = (0.0, 0)
    for lag in range(-max_lag, max_lag + 1):
        c = ncc(a, shift_samples(b, -lag))
        if abs(c) > abs(best[0]):
            best = (c, lag)
    return best


def window(trace: FloatArray, t0_ns: float, half_ns: float, dt_ns: float) -> FloatArray:
    """The samples of a trace within t0 ± half (zero-padded at the trace's ends)."""
    n = round(half_ns / dt_ns)
    k0 = round(t0_ns / dt_ns)
    out = np.zeros(2 * n + 1)
    lo, hi = max(0, k0 - n), min(len(trace), k0 + n + 1)
    if hi > lo:
        out[lo - (k0 - n): hi - (k0 - n)] = trace[lo:hi]
    return out


def flank_x(r: Reflector, angle_deg: float, side: int) -> float:
    """Antenna x whose ray to the target's centre leaves it at `angle_deg` from vertical in the ground."""
    return r.x_m + side * r.depth_m * math.tan(math.radians(angle_deg))
