"""Domain randomisation of the forward model: what antennas and surveys vary, drawn per line for training only.

The default simulator (no variation) is one idealised antenna: a zero-phase Ricker at the nominal
frequency, a cos³ footprint, fixed gain and noise. The FDTD calibration (docs/eval/sim_vs_fdtd.md) shows
that a received wavelet is phase-rotated (0…−90°), peaks at 1.0–1.25 × the nominal frequency, rings, and
may be recorded with either sign, and that flanks fall off slower than cos³; real antennas also differ in
gain, noise, clutter and height. Those are spreads, not values to fit, so training data draw one
`SignalVariation` per line from the ranges of a `DomainRandomisation`, seeded by the caller's generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import scipy.fft
from numpy.typing import NDArray

from gprbot.config import GprConfig
from gprbot.gpr.wavelet import ricker
from gprbot.sim.reflectors import FOOTPRINT_POWER

FloatArray = NDArray[np.float64]

_PULSE_HALF_WIDTH_PERIODS = 1.5  # a zero-phase Ricker is below 1e-9 of its peak beyond this
_ROTATED_HALF_WIDTH_PERIODS = 4.0  # its Hilbert transform decays only as 1/t³
_RING_DELAY_PERIODS = 0.5  # the ring-down starts as the pulse's main lobe ends
_RING_SPAN_DECAYS = 5.0  # the ring is kept until it has decayed by e⁻⁵


@dataclass(frozen=True)
class SignalVariation:
    """One line's recording as it differs from the default simulator (the defaults change nothing)."""

    phase_deg: float = 0.0  # constant phase rotation of the Ricker (spectrum × e^{iφ} at positive frequencies)
    peak_factor: float = 1.0  # the wavelet peaks at peak_factor × the nominal centre frequency
    ring_amplitude: float = 0.0  # antenna ring-down after the pulse, relative to its peak
    ring_decay_periods: float = 1.5  # e-folding time of the ring-down, in periods
    footprint_power: float = FOOTPRINT_POWER  # reflection amplitude ∝ cos(θ)^footprint_power
    polarity: float = 1.0  # −1: the recording's sign convention is the opposite one
    gain: float = 1.0  # overall receiver gain
    gain_db_per_ns: float = 0.0  # a residual time-varying gain after the transmit instant
    noise_factor: float = 1.0  # × the configured receiver noise
    clutter_gain: float = 1.0  # × the aggregate clutter's reflection coefficients
    antenna_height_m: float | None = None  # None: the configured height

    @property
    def is_identity(self) -> bool:
        """Whether this variation leaves the default simulator unchanged."""
        return self == SignalVariation()

    def half_width_periods(self) -> float:
        """How far (periods) the wavelet reaches from its centre."""
        pulse = _PULSE_HALF_WIDTH_PERIODS if self.phase_deg == 0.0 else _ROTATED_HALF_WIDTH_PERIODS
        if self.ring_amplitude > 0.0:
            pulse = max(pulse, _RING_DELAY_PERIODS + _RING_SPAN_DECAYS * self.ring_decay_periods)
        return pulse / self.peak_factor


@dataclass(frozen=True)
class DomainRandomisation:
    """Ranges of `SignalVariation` for training data: (low, high) uniform, log-uniform for factors."""

    phase_deg: tuple[float, float] = (-90.0, 90.0)  # FDTD: about −45° (2D line source), a 3D dipole −90°
    peak_factor: tuple[float, float] = (1.0, 1.25)  # FDTD direct wave 1.15 f, apex 1.17 f
    ring_probability: float = 0.5
    ring_amplitude: tuple[float, float] = (0.05, 0.3)
    ring_decay_periods: tuple[float, float] = (0.7, 2.0)
    footprint_power: tuple[float, float] = (0.5, 3.0)  # FDTD flanks fit cos^0…cos^1.8; ours is cos³
    polarity_flip_probability: float = 0.5  # gprMax records the opposite sign of ours
    gain: tuple[float, float] = (0.5, 2.0)
    gain_db_per_ns: tuple[float, float] = (-0.5, 0.5)
    noise_factor: tuple[float, float] = (0.5, 8.0)
    clutter_gain: tuple[float, float] = (0.5, 3.0)
    clutter_probability: float = 0.5  # of adding aggregate clutter to a scene that has none
    antenna_height_m: tuple[float, float] = (0.0, 0.05)

    def draw(self, rng: np.random.Generator) -> SignalVariation:
        """One line's variation."""

        def uniform(span: tuple[float, float]) -> float:
            return float(rng.uniform(*span))

        def log_uniform(span: tuple[float, float]) -> float:
            return math.exp(rng.uniform(math.log(span[0]), math.log(span[1])))

        ring = rng.random() < self.ring_probability
        return SignalVariation(
            phase_deg=uniform(self.phase_deg),
            peak_factor=uniform(self.peak_factor),
            ring_amplitude=uniform(self.ring_amplitude) if ring else 0.0,
            ring_decay_periods=uniform(self.ring_decay_periods),
            footprint_power=uniform(self.footprint_power),
            polarity=-1.0 if rng.random() < self.polarity_flip_probability else 1.0,
            gain=log_uniform(self.gain),
            gain_db_per_ns=uniform(self.gain_db_per_ns),
            noise_factor=log_uniform(self.noise_factor),
            clutter_gain=log_uniform(self.clutter_gain),
            antenna_height_m=uniform(self.antenna_height_m),
        )


def varied_config(gpr: GprConfig, variation: SignalVariation) -> GprConfig:
    """The antenna settings a variation implies: its height and noise (what the caller must also interpret with)."""
    height = gpr.antenna_height_m if variation.antenna_height_m is None else variation.antenna_height_m
    return replace(gpr, antenna_height_m=height, noise_mv=gpr.noise_mv * variation.noise_factor)


def wavelet_kernel(lags_ns: FloatArray, centre_frequency_mhz: float, variation: SignalVariation,
                   half: int, dt_ns: float) -> FloatArray:
    """The wavelet on circular lags (n_fft,) centred on lag 0, zero beyond `half` samples: rotated, peaked, ringing."""
    f = centre_frequency_mhz * variation.peak_factor
    kernel = np.where(np.abs(lags_ns) <= half * dt_ns, ricker(lags_ns, f), 0.0)
    if variation.phase_deg != 0.0:
        spectrum = scipy.fft.rfft(kernel)
        spectrum[1:] *= np.exp(1j * math.radians(variation.phase_deg))  # DC stays real (and is ~0)
        kernel = scipy.fft.irfft(spectrum, len(kernel))
    if variation.ring_amplitude > 0.0:
        period = 1e3 / f
        u = lags_ns - _RING_DELAY_PERIODS * period
        decay = np.exp(-np.maximum(u, 0.0) / (variation.ring_decay_periods * period))
        ring = np.sin(2.0 * math.pi * u / period) * decay
        kernel = kernel + variation.ring_amplitude * np.where(u > 0.0, ring, 0.0)
    return np.asarray(np.where(np.abs(lags_ns) <= half * dt_ns, kernel, 0.0))


def apply_gain(traces: FloatArray, gpr: GprConfig, variation: SignalVariation) -> FloatArray:
    """The recording's sign and gain: overall, times a gain ramp after the transmit instant."""
    t = np.arange(traces.shape[1]) * gpr.dt_ns - gpr.pre_trigger_ns
    ramp = 10.0 ** (variation.gain_db_per_ns * np.maximum(t, 0.0) / 20.0)
    return np.asarray(traces * (variation.polarity * variation.gain * ramp)[None, :])
