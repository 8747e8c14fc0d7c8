"""The GPR forward model: B-scans of a scene by ray tracing to specular points, vectorised over traces.

Each reflector contributes an event (arrival time, amplitude) per trace; the events are laid on a
padded time axis as fractional-sample spikes and convolved with a Ricker wavelet by FFT, then the
receiver's low-frequency "wow" and Gaussian noise are added. Amplitude calibration and reflection
coefficients are in `gprbot.sim.reflectors`.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft
from numpy.typing import NDArray

from gprbot.config import GprConfig
from gprbot.gpr.traveltime import C_M_PER_NS, two_way_time, velocity_from_eps
from gprbot.gpr.wavelet import ricker
from gprbot.sim.reflectors import (
    DIRECT_WAVE_MV,
    GROUND_WAVE_MV,
    SOURCE_MV_M,
    WOW_MV,
    Events,
    clutter_events,
    interface_coefficient,
    pipe_events,
    shadow_factor,
    slab_bottom_coefficient,
)
from gprbot.sim.scene import Pipe, Scene
from gprbot.sim.variation import SignalVariation, apply_gain, varied_config, wavelet_kernel

FloatArray = NDArray[np.float64]

_MIN_SURFACE_PATH_M = 0.3  # near field: the surface echo of a ground-coupled antenna is a fraction of the direct wave


def simulate_bscan(
    scene: Scene,
    mid_xy: NDArray[np.float64],
    gpr: GprConfig,
    rng: np.random.Generator,
    offset_dir: NDArray[np.float64] | tuple[float, float] = (1.0, 0.0),
    variation: SignalVariation | None = None,
) -> NDArray[np.float32]:
    """Traces (N, gpr.samples) in mV recorded with the antenna midpoint at the TRUE positions mid_xy (N, 2).

    `offset_dir` is the horizontal unit vector from Rx to Tx in the site frame. Sample k lies at
    k * gpr.dt_ns - gpr.pre_trigger_ns after the transmit instant. `variation` (training data only)
    changes the wavelet, footprint, gain, noise, clutter and height; interpret its line with
    `varied_config(gpr, variation)`.
    """
    mid = np.asarray(mid_xy, dtype=np.float64)
    if mid.ndim != 2 or mid.shape[1] != 2:
        raise ValueError(f"mid_xy must have shape (N, 2), got {mid.shape}")
    direction = np.asarray(offset_dir, dtype=np.float64)
    if direction.shape != (2,) or not np.any(direction):
        raise ValueError(f"offset_dir must be a non-zero horizontal vector (2,), got {offset_dir!r}")
    direction = direction / float(np.hypot(direction[0], direction[1]))
    if len(mid) == 0:
        return np.zeros((0, gpr.samples), dtype=np.float32)
    variation = variation or SignalVariation()
    gpr = varied_config(gpr, variation)

    events = Events(len(mid))
    _add_air_and_surface_waves(events, scene, mid, gpr)
    reflectors = (*scene.pipes, *scene.rebar_bars())
    _add_slab_bottom(events, scene, reflectors, mid, gpr, direction)
    pipe_events(events, reflectors, scene.slab, mid, gpr, direction, variation.footprint_power)
    if scene.clutter is not None:
        clutter_events(events, scene.clutter, scene.slab, mid, gpr, direction, variation.footprint_power,
                       variation.clutter_gain)
    bscan = render_events(events, gpr, variation)
    bscan += receiver_drift(len(mid), gpr, rng)
    if gpr.noise_mv > 0:
        bscan += rng.normal(0.0, gpr.noise_mv, size=bscan.shape)
    if not variation.is_identity:
        bscan = apply_gain(bscan, gpr, variation)
    return bscan.astype(np.float32)


def _add_air_and_surface_waves(events: Events, scene: Scene, mid: FloatArray, gpr: GprConfig) -> None:
    """Direct air wave Tx→Rx, ground wave along the surface, and the surface reflection."""
    n_traces = len(mid)
    h, offset = gpr.antenna_height_m, gpr.tx_rx_offset_m
    v = velocity_from_eps(scene.slab.eps_r)
    ones = np.ones(n_traces)
    events.add(ones * (offset / C_M_PER_NS), ones * DIRECT_WAVE_MV)
    events.add(ones * (2.0 * h / C_M_PER_NS + offset / v), ones * GROUND_WAVE_MV)
    leg = math.hypot(h, offset / 2.0)
    coefficient = interface_coefficient(1.0, scene.slab.eps_r)  # air → concrete: negative
    amplitude = SOURCE_MV_M * coefficient / max(2.0 * leg, _MIN_SURFACE_PATH_M)
    events.add(ones * (2.0 * leg / C_M_PER_NS), ones * amplitude)


def _add_slab_bottom(
    events: Events, scene: Scene, shadowing: tuple[Pipe, ...], mid: FloatArray, gpr: GprConfig, direction: FloatArray
) -> None:
    """The slab bottom as a flat reflector, dimmed where the pipes and bars above shadow it."""
    slab = scene.slab
    v = velocity_from_eps(slab.eps_r)
    point = np.concatenate([mid, np.full((len(mid), 1), -slab.thickness_m)], axis=1)
    t = two_way_time(mid, point, v, gpr.antenna_height_m, gpr.tx_rx_offset_m, direction)
    x0, y0 = slab.origin_m
    on_slab = (
        (mid[:, 0] >= x0) & (mid[:, 0] <= x0 + slab.size_m[0]) & (mid[:, 1] >= y0) & (mid[:, 1] <= y0 + slab.size_m[1])
    )
    path = 2.0 * (slab.thickness_m + gpr.antenna_height_m)
    attenuation = 10.0 ** (-slab.loss_db_per_m * 2.0 * slab.thickness_m / 20.0)
    n = math.sqrt(slab.eps_r)
    transmission = 4.0 * n / (1.0 + n) ** 2
    amplitude = SOURCE_MV_M * transmission * slab_bottom_coefficient(slab) * attenuation / path
    shadow = shadow_factor(shadowing, mid, gpr.centre_frequency_mhz, v)
    events.add(t, amplitude * shadow * on_slab)


def render_events(events: Events, gpr: GprConfig, variation: SignalVariation | None = None) -> FloatArray:
    """Lay the events as fractional-sample spikes on each trace and convolve them with the wavelet.

    The wavelet is the Ricker at the nominal frequency, or the one a (training-only) variation describes.
    """
    n_traces = events.n_traces
    rows, times, amplitudes = events.flat()
    dt = gpr.dt_ns
    variation = variation or SignalVariation()
    half = math.ceil(variation.half_width_periods() / (gpr.centre_frequency_mhz * 1e-3 * dt))
    padded = gpr.samples + 2 * half
    position = (times + gpr.pre_trigger_ns) / dt + half
    keep = (position >= 0.0) & (position < padded - 1) & (amplitudes != 0.0)
    rows, position, weight = rows[keep], position[keep], amplitudes[keep]
    k0 = np.floor(position).astype(np.int64)
    frac = position - k0
    flat = rows * padded + k0
    # Linear split between the two neighbouring samples keeps the event's centroid exact.
    spikes = np.bincount(flat, weight * (1.0 - frac), minlength=n_traces * padded)
    spikes += np.bincount(flat + 1, weight * frac, minlength=n_traces * padded)
    spikes = spikes.reshape(n_traces, padded)
    # A kernel centred on lag 0 (negative lags wrapped) needs no more than `padded` points to avoid aliasing.
    n_fft = scipy.fft.next_fast_len(padded, real=True)
    lags = np.arange(n_fft)
    lags = np.where(lags > n_fft // 2, lags - n_fft, lags)
    if variation.is_identity:
        kernel = np.where(np.abs(lags) <= half, ricker(lags * dt, gpr.centre_frequency_mhz), 0.0)
    else:
        kernel = wavelet_kernel(lags * dt, gpr.centre_frequency_mhz, variation, half, dt)
    spectrum = scipy.fft.rfft(spikes, n_fft, axis=1) * scipy.fft.rfft(kernel)
    traces = scipy.fft.irfft(spectrum, n_fft, axis=1)
    return np.ascontiguousarray(traces[:, half : half + gpr.samples])


def receiver_drift(n_traces: int, gpr: GprConfig, rng: np.random.Generator) -> FloatArray:
    """The slow "wow" of each trace: a low-frequency swell after the direct wave plus a DC offset."""
    amplitude = WOW_MV * (1.0 + 0.25 * rng.standard_normal(n_traces))
    rise_ns = np.clip(3.0 * (1.0 + 0.2 * rng.standard_normal(n_traces)), 1.0, None)
    dc = rng.normal(0.0, 5.0, n_traces)
    t = np.arange(gpr.samples) * gpr.dt_ns  # from the first sample, so the swell starts with the trace
    u = t[None, :] / rise_ns[:, None]
    return np.asarray(amplitude[:, None] * u * np.exp(1.0 - u) + dc[:, None])
