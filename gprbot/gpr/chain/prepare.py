"""Stage 1 of the interpretation chain: a raw B-scan → a PreparedBScan (time zero and wavelet from the data).

Nothing here assumes the simulator's physics: time zero comes from the direct wave's envelope peak in
the line's median trace, the dominant frequency from the spectrum of the background-removed traces, and
the noise level from their robust spread. Order: uniform grid, dewow, direct wave, median background.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from gprbot.config import GprConfig
from gprbot.gpr.bscan import BScan, checked_along_track
from gprbot.gpr.chain.peaks import peak_offset
from gprbot.gpr.migration import resample_uniform
from gprbot.gpr.preprocess import BACKGROUND_WINDOW_M, DEWOW, dewow, remove_background, remove_gain
from gprbot.gpr.traveltime import C_M_PER_NS

FloatArray = NDArray[np.float64]

_DIRECT_SEARCH_FRACTION = 0.6  # the direct wave lies in the first part of any sensible window
_MIN_FREQUENCY_RATIO, _MAX_FREQUENCY_RATIO = 0.25, 3.0  # band searched around the nominal frequency
SAMPLES_PER_PERIOD = 16  # finer time sampling adds cost and no information: decimate down to it
SHORT_LINE_WAVELENGTHS = 3.0  # shorter lines (at 0.1 m/ns) keep their median trace below the direct wave
NOMINAL_V_M_PER_NS = 0.1
DIRECT_WAVE_PERIODS = 1.0  # the direct wave's main lobes last about this long after its envelope peak


@dataclass(frozen=True)
class PreparedBScan:
    """A line on a uniform along-track grid: dewowed, background removed, no gain; wavelet facts from the data."""

    data: FloatArray  # (nx, ns)
    envelope: FloatArray  # Hilbert envelope of data along time
    x_m: FloatArray  # along-track grid (m from the first trace)
    dt_ns: float
    t0_ns: float  # transmit instant, ns after sample 0
    t0_method: str
    frequency_mhz: float  # dominant frequency of the reflections, from their spectrum
    noise: float  # robust standard deviation of the background-removed samples
    direct_polarity: float  # sign of the direct wave's main lobe
    antenna_height_m: float
    tx_rx_offset_m: float
    decimation: int = 1  # time samples merged into one (anti-aliased) to bound the cost

    @functools.cached_property
    def data32(self) -> NDArray[np.float32]:
        """`data` in single precision, made once: the semblance and focus gathers read it (half the traffic)."""
        return self.data.astype(np.float32)

    @property
    def period_ns(self) -> float:
        """One period of the dominant frequency (ns)."""
        return 1000.0 / self.frequency_mhz

    def wavelength_m(self, v: float) -> float:
        """One dominant wavelength (m) at velocity v (m/ns)."""
        return v * self.period_ns

    @property
    def dx_m(self) -> float:
        """Grid spacing along the line (m)."""
        return float(self.x_m[1] - self.x_m[0])


def _direct_wave(mean_trace: FloatArray, dt_ns: float) -> tuple[float, float]:
    """(time of the direct wave's envelope peak in ns from sample 0, sign of its largest lobe).

    The direct wave is the strongest event of the line's median trace (reflections are far weaker and
    the median keeps only what every trace shares); it is looked for in the first part of the window.
    """
    n = max(8, int(len(mean_trace) * _DIRECT_SEARCH_FRACTION))
    env = np.abs(signal.hilbert(mean_trace))[:n]
    i = int(np.argmax(env))
    frac = peak_offset(env, i)
    half = max(1, n // 20)
    lobe = max(0, i - half) + int(np.argmax(np.abs(mean_trace[max(0, i - half) : i + half + 1])))
    return (i + frac) * dt_ns, 1.0 if mean_trace[lobe] >= 0 else -1.0


def dominant_frequency(data: FloatArray, dt_ns: float, start: int, nominal_mhz: float) -> float:
    """Peak of the smoothed power spectrum of the traces after sample `start` (MHz), near the nominal one."""
    late = data[:, start:]
    if late.shape[1] < 8:
        return nominal_mhz
    n = 1 << math.ceil(math.log2(2 * late.shape[1]))
    power = np.mean(np.abs(np.fft.rfft(late * np.hanning(late.shape[1])[None, :], n=n, axis=1)) ** 2, axis=0)
    freq = np.fft.rfftfreq(n, dt_ns) * 1000.0
    band = (freq >= _MIN_FREQUENCY_RATIO * nominal_mhz) & (freq <= _MAX_FREQUENCY_RATIO * nominal_mhz)
    if not band.any():
        return nominal_mhz
    smooth = np.convolve(power, np.ones(5) / 5.0, mode="same")
    # Centroid of the band's upper half-power region: steadier than the raw argmax of a noisy spectrum.
    b = np.where(band, smooth, 0.0)
    top = b >= 0.5 * b.max()
    return float(np.sum(freq[top] * b[top]) / np.sum(b[top]))


def grid_spacing(along_m: FloatArray, centre_frequency_mhz: float) -> float:
    """Along-track grid step: the mean trace step, but traces denser than λ/16 (at 0.1 m/ns, ≤ 1 cm) are binned.

    A line is never interpolated finer than it was recorded (a 100 MHz line at 25 cm stays at 25 cm).
    """
    mean_step = float(np.ptp(along_m)) / max(len(along_m) - 1, 1)
    finest = min(0.01, 0.1 / (centre_frequency_mhz / 1000.0) / 16.0)
    return max(mean_step, finest)


def decimation_factor(dt_ns: float, centre_frequency_mhz: float) -> int:
    """Integer factor that brings the sampling down to about SAMPLES_PER_PERIOD per nominal period."""
    per_period = 1000.0 / (centre_frequency_mhz * dt_ns)
    return max(1, int(per_period // SAMPLES_PER_PERIOD))


def noise_level(data: FloatArray, blocks: int = 8) -> float:
    """Robust standard deviation of the quietest of `blocks` time windows (signal fills the others)."""
    n = data.shape[1]
    if n < 2 * blocks:
        return float(1.4826 * np.median(np.abs(data - np.median(data))))
    edges = np.linspace(0, n, blocks + 1).astype(int)
    return float(min(1.4826 * np.median(np.abs(data[:, a:b] - np.median(data[:, a:b])))
                     for a, b in itertools.pairwise(edges)))


def without_direct_wave(data: FloatArray, direct_ns: float, dt_ns: float, period_ns: float) -> FloatArray:
    """The traces less their median over the direct wave only: in full for DIRECT_WAVE_PERIODS after its peak,
    then tapered to nothing over one more period.

    On a line not much longer than one hyperbola is wide, most traces see the same apex, so the median
    trace holds the target and subtracting it all the way down erases it; only the direct wave is
    shared for sure.
    """
    t = np.arange(data.shape[1]) * dt_ns
    ramp = np.clip((t - direct_ns - DIRECT_WAVE_PERIODS * period_ns) / period_ns, 0.0, 1.0)
    taper = 0.5 * (1.0 + np.cos(np.pi * ramp))
    return np.asarray(data - np.median(data, axis=0)[None, :] * taper[None, :], dtype=np.float64)


def prepare(bscan: BScan, gpr: GprConfig) -> PreparedBScan:
    """Uniform grid, dewow, time zero from the direct wave (unless known), median background removal."""
    along = checked_along_track(bscan)  # the gain changes the data only: the line's coordinates stand
    raw = remove_gain(bscan)
    data, x = resample_uniform(raw, grid_spacing(along, gpr.centre_frequency_mhz), along_m=along)
    q = decimation_factor(raw.dt_ns, gpr.centre_frequency_mhz)
    if q > 1:
        data = np.asarray(signal.resample_poly(data, 1, q, axis=1), dtype=np.float32)
        raw = replace(raw, dt_ns=raw.dt_ns * q)
    dewowed = np.asarray(data if DEWOW in raw.processing else dewow(data, raw.dt_ns, gpr.centre_frequency_mhz),
                         dtype=np.float64)
    direct_ns, polarity = _direct_wave(np.median(dewowed, axis=0), raw.dt_ns)
    if math.isfinite(raw.t0_ns):
        t0, method = raw.t0_ns, "given"
    else:
        # The envelope peak of the direct wave is where the Tx→Rx air path ends; reflections are timed at
        # their envelope peaks too, so the wavelet's own delay cancels.
        path = 0.5 * (gpr.tx_rx_offset_m + math.hypot(gpr.tx_rx_offset_m, 2.0 * gpr.antenna_height_m))
        t0, method = direct_ns - path / C_M_PER_NS, "direct-wave envelope peak"
    length = float(x[-1] - x[0])
    period_ns = 1000.0 / gpr.centre_frequency_mhz
    if length < SHORT_LINE_WAVELENGTHS * NOMINAL_V_M_PER_NS * period_ns:
        cleaned = without_direct_wave(dewowed, direct_ns, raw.dt_ns, period_ns)
    else:
        window = BACKGROUND_WINDOW_M if length > BACKGROUND_WINDOW_M else None
        cleaned = np.asarray(remove_background(dewowed, x, window_m=window, spacing_m=float(x[1] - x[0])), np.float64)
    start = min(cleaned.shape[1] - 1, max(0, round(direct_ns / raw.dt_ns)))
    freq = dominant_frequency(cleaned, raw.dt_ns, start, gpr.centre_frequency_mhz)
    noise = noise_level(cleaned[:, start:]) or float(np.std(cleaned)) or 1e-12
    env = np.abs(signal.hilbert(cleaned, axis=1))
    return PreparedBScan(cleaned, env, x, raw.dt_ns, float(t0), method, freq, noise, polarity,
                         gpr.antenna_height_m, gpr.tx_rx_offset_m, q)
