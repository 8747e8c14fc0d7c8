"""Reflectors of the forward model: pipes, rebar bars, clutter scatterers, and their amplitudes.

Amplitude of a reflection seen from one trace (mV):
    SOURCE_MV_M · T · C · size · cos(θ)^FOOTPRINT_POWER · 10^(-loss · 2d / 20) / (2 (d + h))
with T = 4n/(1+n)² the two-way transmission through the surface, C the reflection coefficient, d the
distance from the ground point under the antenna to the specular point, θ that ray's angle from
vertical, h the antenna height. Coefficients are normal-incidence Fresnel coefficients of the field,
C = (n1 - n2) / (n1 + n2) going from medium 1 into medium 2, so metal is -1 and concrete→air is positive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.config import GprConfig
from gprbot.gpr.traveltime import C_M_PER_NS, cylinder_specular_point, two_way_time, velocity_from_eps
from gprbot.sim.scene import Clutter, Fill, Pipe, Slab

FloatArray = NDArray[np.float64]

# Calibration (see module docstring), at 900 MHz from 2 cm height over concrete of eps_r 6.25 and 15 dB/m:
# a steel pipe of radius 3 cm with its axis at 15 cm (top at 12 cm) peaks at -300 mV, and the early blob
# (direct wave + surface echo + ground wave) at about +1000 mV, the ratio a ground-coupled 900 MHz antenna
# shows between its direct coupling and a shallow pipe. DIRECT_WAVE_MV is set so that the blob, after the
# negative surface echo overlaps it, peaks near 1000 mV.
SOURCE_MV_M = 165.0
DIRECT_WAVE_MV = 1300.0
GROUND_WAVE_MV = 300.0
WOW_MV = 80.0
FOOTPRINT_POWER = 3.0  # cos³θ: the flanks of a hyperbola beyond ~45° fade below a third of the apex
# The pipe → surface → pipe multiple relative to top² × (surface coefficient from below). Was 0.5; the FDTD
# dev half puts the multiple at 0.110 of the primary over metal pipes against ours' 0.212, and the FDTD's
# 2D spreading makes a multiple stronger than a 3D one would be, so about half of the old factor is an
# upper bound (docs/eval/sim_vs_fdtd.md).
SURFACE_MULTIPLE = 0.25
END_TAPER_M = 0.03  # a pipe's open end diffracts weakly: fade its echo over 3 cm past the end
_CLUTTER_COEFFICIENT = (0.05, 0.3)  # aggregate / voids: weak contrasts of either sign
CLUTTER_CUTOFF_MV = 0.01  # clutter echoes weaker than this are not traced (noise is ~0.5 mV)


@dataclass(frozen=True)
class FillOptics:
    """What a pipe's fill does to a wave: permittivity (None: metal), wall factor, loss, shadowing."""

    eps_r: float | None
    wall_factor: float  # a thin PVC wall between concrete and water interferes destructively
    loss_db_per_m: float
    shadow: float  # fraction of the slab-bottom echo blocked right under the pipe


FILL_OPTICS: dict[Fill, FillOptics] = {
    "metal": FillOptics(None, 1.0, 0.0, 0.6),
    # PVC-air: against metal the FDTD's echo is 1/1.23 of ours (dev half) and its inner-bottom echo much
    # weaker; the 5–6 mm wall (concrete→PVC→air) and the bore's defocusing are not modelled, so the wall
    # factor stands for both: top × 0.8, inner echo × 0.64.
    "pvc-air": FillOptics(1.0, 0.8, 0.0, 0.3),
    "pvc-water": FillOptics(81.0, 0.5, 80.0, 0.5),  # tap water near 1 GHz: strongly absorbing
}


class Events:
    """Reflection events: for each, the trace it belongs to, its arrival time (ns) and amplitude (mV)."""

    def __init__(self, n_traces: int) -> None:
        self.n_traces = n_traces
        self._rows: list[NDArray[np.int64]] = []
        self._times: list[FloatArray] = []
        self._amplitudes: list[FloatArray] = []

    def add(self, times: FloatArray, amplitudes: FloatArray) -> None:
        """Add one event per trace (times (N,)) or m events per trace (times (N, m))."""
        t = np.asarray(times, dtype=np.float64).reshape(self.n_traces, -1)
        a = np.broadcast_to(np.asarray(amplitudes, dtype=np.float64).reshape(self.n_traces, -1), t.shape)
        rows = np.broadcast_to(np.arange(self.n_traces)[:, None], t.shape)
        self.add_sparse(rows.ravel(), t.ravel(), a.ravel())

    def add_sparse(self, rows: NDArray[np.int64], times: FloatArray, amplitudes: FloatArray) -> None:
        """Add events of the given traces (1-D arrays of equal length)."""
        self._rows.append(np.asarray(rows, dtype=np.int64))
        self._times.append(np.asarray(times, dtype=np.float64))
        self._amplitudes.append(np.asarray(amplitudes, dtype=np.float64))

    def flat(self) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
        """All events as 1-D arrays: trace index, time, amplitude."""
        if not self._rows:
            return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
        return np.concatenate(self._rows), np.concatenate(self._times), np.concatenate(self._amplitudes)


def interface_coefficient(eps_from: float, eps_to: float) -> float:
    """Normal-incidence reflection coefficient of the field going from one dielectric into another."""
    n1, n2 = math.sqrt(eps_from), math.sqrt(eps_to)
    return (n1 - n2) / (n1 + n2)


def slab_bottom_coefficient(slab: Slab) -> float:
    """Reflection coefficient of the slab's bottom face (concrete onto what lies below: soil or air)."""
    return interface_coefficient(slab.eps_r, slab.below_eps_r)


def _ray_amplitude(points: FloatArray, mid: FloatArray, slab: Slab, gpr: GprConfig,
                   footprint_power: float = FOOTPRINT_POWER) -> tuple[FloatArray, FloatArray]:
    """(distance d, amplitude without coefficient and size) for points (N, m, 3) seen from mid (N, 2)."""
    horizontal = points[..., :2] - mid[:, None, :]
    depth = -points[..., 2]
    d = np.sqrt(np.sum(horizontal**2, axis=-1) + depth**2)
    cos_theta = depth / np.maximum(d, 1e-9)
    n = math.sqrt(slab.eps_r)
    transmission = 4.0 * n / (1.0 + n) ** 2
    attenuation = 10.0 ** (-slab.loss_db_per_m * 2.0 * d / 20.0)
    spreading = 1.0 / (2.0 * (d + gpr.antenna_height_m))
    return d, SOURCE_MV_M * transmission * cos_theta**footprint_power * attenuation * spreading


def _segment_weights(s: FloatArray, lengths: FloatArray) -> FloatArray:
    """How much of each segment's echo is real, from the projection parameters s (N, S) on each segment.

    A projection inside a segment is a true specular point (weight 1). Past an interior joint it is a
    specular point only when the neighbouring segment is also past that joint (the outside of the bend,
    where both see the joint: 0.5 each); otherwise the neighbour's own specular point stands for it (0).
    Past the pipe's ends the echo fades over END_TAPER_M.
    """
    w = np.ones_like(s)
    before, after = s < 0.0, s > 1.0
    w[:, 0] = np.where(before[:, 0], np.exp(-((s[:, 0] * lengths[0] / END_TAPER_M) ** 2)), w[:, 0])
    beyond_end = (s[:, -1] - 1.0) * lengths[-1] / END_TAPER_M
    w[:, -1] = np.where(after[:, -1], np.exp(-(beyond_end**2)), w[:, -1])
    for j in range(1, s.shape[1]):
        both = after[:, j - 1] & before[:, j]
        w[:, j - 1] = np.where(after[:, j - 1], np.where(both, 0.5, 0.0), w[:, j - 1])
        w[:, j] = np.where(before[:, j], np.where(both, 0.5, 0.0), w[:, j])
    return w


def pipe_events(
    events: Events, pipes: tuple[Pipe, ...], slab: Slab, mid: FloatArray, gpr: GprConfig, direction: FloatArray,
    footprint_power: float = FOOTPRINT_POWER,
) -> None:
    """Echoes of every pipe segment: the top, a PVC pipe's inner bottom, and the first surface multiple."""
    if not pipes:
        return
    ground = np.concatenate([mid, np.zeros((len(mid), 1))], axis=1)
    points: list[FloatArray] = []
    weights: list[FloatArray] = []
    radii: list[float] = []
    fills: list[Fill] = []
    for pipe in pipes:
        params, lengths = [], []
        for a, b in pipe.segments():
            p, _ = cylinder_specular_point(mid, a, b, pipe.radius_m)
            ab = b - a
            params.append(((ground - a) @ ab) / float(ab @ ab))
            lengths.append(float(np.linalg.norm(ab)))
            points.append(p)
            radii.append(pipe.radius_m)
            fills.append(pipe.fill)
        weights.append(_segment_weights(np.stack(params, axis=1), np.array(lengths)))
    P = np.stack(points, axis=1)  # (N, S, 3)
    W = np.concatenate(weights, axis=1)
    R = np.array(radii)
    v = velocity_from_eps(slab.eps_r)
    wavelength = v / (gpr.centre_frequency_mhz * 1e-3)
    size = np.minimum(1.0, np.sqrt(R / (wavelength / 4.0)))  # thin bars echo less than the wavelength
    response = np.array([_fill_response(f, r, slab.eps_r) for f, r in zip(fills, radii, strict=True)])
    top, inner, delay = response[:, 0], response[:, 1], response[:, 2]
    t = two_way_time(mid[:, None, :], P, v, gpr.antenna_height_m, gpr.tx_rx_offset_m, direction)
    d, base = _ray_amplitude(P, mid, slab, gpr, footprint_power)
    amplitude = base * W * size
    events.add(t, amplitude * top)
    events.add(t + delay, amplitude * inner)
    surface_from_below = interface_coefficient(slab.eps_r, 1.0)
    extra_loss = 10.0 ** (-slab.loss_db_per_m * 2.0 * d / 20.0)
    events.add(t + 2.0 * d / v, amplitude * top * top * surface_from_below * SURFACE_MULTIPLE * extra_loss)


def _fill_response(fill: Fill, radius: float, eps_slab: float) -> tuple[float, float, float]:
    """(top coefficient, inner-bottom coefficient, inner-bottom delay in ns) of a pipe."""
    optics = FILL_OPTICS[fill]
    if optics.eps_r is None:
        return -1.0, 0.0, 0.0
    raw = interface_coefficient(eps_slab, optics.eps_r)
    n_fill = math.sqrt(optics.eps_r)
    inside_path = 4.0 * radius  # down and back up the diameter: the radial ray meets both walls normally
    inside_loss = 10.0 ** (-optics.loss_db_per_m * inside_path / 20.0)
    inner = -raw * (1.0 - raw * raw) * optics.wall_factor**2 * inside_loss
    return raw * optics.wall_factor, inner, inside_path * n_fill / C_M_PER_NS


def shadow_factor(pipes: tuple[Pipe, ...], mid: FloatArray, centre_frequency_mhz: float, v: float) -> FloatArray:
    """Fraction (N,) of the slab-bottom echo that reaches each trace past the pipes above it."""
    wavelength = v / (centre_frequency_mhz * 1e-3)
    factor = np.ones(len(mid))
    for pipe in pipes:
        block = FILL_OPTICS[pipe.fill].shadow
        width = pipe.radius_m + wavelength / 4.0
        for a, b in pipe.segments():
            ab = (b - a)[:2]
            s = np.clip(((mid - a[:2]) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
            d = np.linalg.norm(mid - (a[:2] + s[:, None] * ab), axis=1)
            factor *= 1.0 - block * np.exp(-((d / width) ** 2))
    return factor


def clutter_scatterers(clutter: Clutter, slab: Slab) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The clutter's scatterers, fixed by its seed: points (M, 3), radii (M,), reflection coefficients (M,)."""
    rng = np.random.default_rng(clutter.seed)
    m = clutter.count
    x = slab.origin_m[0] + slab.size_m[0] * rng.random(m)
    y = slab.origin_m[1] + slab.size_m[1] * rng.random(m)
    depth = rng.uniform(*clutter.depth_range_m, size=m)
    radii = clutter.max_radius_m * rng.uniform(0.3, 1.0, size=m)
    coefficients = rng.uniform(*_CLUTTER_COEFFICIENT, size=m) * rng.choice([-1.0, 1.0], size=m)
    return np.stack([x, y, -depth], axis=1), radii, coefficients


def clutter_events(
    events: Events, clutter: Clutter, slab: Slab, mid: FloatArray, gpr: GprConfig, direction: FloatArray,
    footprint_power: float = FOOTPRINT_POWER, gain: float = 1.0,
) -> None:
    """Point-scatterer echoes of the aggregate clutter (coefficients × gain)."""
    if clutter.count == 0:
        return
    points, radii, coefficients = clutter_scatterers(clutter, slab)
    v = velocity_from_eps(slab.eps_r)
    wavelength = v / (gpr.centre_frequency_mhz * 1e-3)
    size = np.minimum(1.0, radii / (wavelength / 4.0)) ** 1.5  # a small sphere scatters less than a rod
    P = np.broadcast_to(points[None], (len(mid), *points.shape))
    _, base = _ray_amplitude(P, mid, slab, gpr, footprint_power)
    amplitude = base * size * coefficients * gain
    # Most (trace, scatterer) pairs are far off the antenna's footprint: trace only those that matter.
    rows, cols = np.nonzero(np.abs(amplitude) > CLUTTER_CUTOFF_MV)
    t = two_way_time(mid[rows], points[cols], v, gpr.antenna_height_m, gpr.tx_rx_offset_m, direction)
    events.add_sparse(rows, t, amplitude[rows, cols])
