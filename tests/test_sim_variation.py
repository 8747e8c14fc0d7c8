"""Domain randomisation of the forward model: identity by default, seeded draws, each spread doing what it says."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gprbot.config import GprConfig
from gprbot.sim.forward import ricker, simulate_bscan
from gprbot.sim.scene import Pipe, Scene, Slab
from gprbot.sim.variation import DomainRandomisation, SignalVariation, varied_config, wavelet_kernel

SLAB = Slab((2.4, 1.2), (-0.2, -0.1), 0.45, 6.25, 15.0)
GPR = GprConfig(noise_mv=0.0)


def _scene() -> Scene:
    pipe = Pipe("p", np.array([[1.0, -0.1, -0.15], [1.0, 1.1, -0.15]]), 0.03, "metal")
    return Scene("t", "", SLAB, (pipe,), None, None)


def _line() -> np.ndarray:
    x = np.arange(0.6, 1.4, 0.01)
    return np.stack([x, np.full_like(x, 0.5)], axis=1)


def _echo(variation: SignalVariation | None) -> np.ndarray:
    """The pipe's echo alone (empty slab subtracted, same seed)."""
    scene = _scene()
    full = simulate_bscan(scene, _line(), GPR, np.random.default_rng(1), variation=variation)
    empty = simulate_bscan(dataclasses.replace(scene, pipes=()), _line(), GPR, np.random.default_rng(1),
                           variation=variation)
    return np.asarray(full, np.float64) - empty


def test_no_variation_and_the_identity_variation_give_the_same_bscan() -> None:
    a = simulate_bscan(_scene(), _line(), GprConfig(), np.random.default_rng(4))
    b = simulate_bscan(_scene(), _line(), GprConfig(), np.random.default_rng(4), variation=SignalVariation())
    assert SignalVariation().is_identity and np.array_equal(a, b)


def test_draws_are_seeded_and_inside_their_ranges() -> None:
    dr = DomainRandomisation()
    draws = [dr.draw(np.random.default_rng([7, i])) for i in range(200)]
    assert draws[3] == dr.draw(np.random.default_rng([7, 3]))
    assert all(dr.phase_deg[0] <= d.phase_deg <= dr.phase_deg[1] for d in draws)
    assert all(dr.footprint_power[0] <= d.footprint_power <= dr.footprint_power[1] for d in draws)
    assert all(d.antenna_height_m is not None and 0.0 <= d.antenna_height_m <= 0.05 for d in draws)
    flipped = sum(d.polarity < 0 for d in draws)
    ringing = sum(d.ring_amplitude > 0 for d in draws)
    assert 60 < flipped < 140 and 60 < ringing < 140


def test_a_90_degree_rotation_keeps_the_energy_and_is_orthogonal_to_the_ricker() -> None:
    dt, f = 0.01, 1000.0
    n = 2048
    lags = np.arange(n)
    lags = np.where(lags > n // 2, lags - n, lags) * dt
    half = 400
    zero = wavelet_kernel(lags, f, SignalVariation(phase_deg=1e-9), half, dt)
    quad = wavelet_kernel(lags, f, SignalVariation(phase_deg=90.0), half, dt)
    assert np.allclose(zero, np.where(np.abs(lags) <= half * dt, ricker(lags, f), 0.0), atol=1e-6)
    assert np.sum(quad**2) == pytest.approx(np.sum(zero**2), rel=0.01)
    assert abs(np.sum(quad * zero)) < 1e-3 * np.sum(zero**2)
    assert abs(quad[0]) < 1e-3  # odd: zero at its centre


def test_higher_peak_factor_shortens_the_wavelet() -> None:
    dt, f = 0.01, 1000.0
    lags = np.arange(-300, 300) * dt
    wide = wavelet_kernel(lags, f, SignalVariation(peak_factor=1.0 + 1e-9), 300, dt)
    narrow = wavelet_kernel(lags, f, SignalVariation(peak_factor=1.25), 300, dt)
    first_zero = [np.argmax(k[300:] < 0) for k in (wide, narrow)]
    assert first_zero[1] == pytest.approx(first_zero[0] / 1.25, abs=1)


def test_ringing_adds_energy_after_the_pulse_only() -> None:
    dt, f = 0.01, 1000.0
    lags = np.arange(-600, 600) * dt
    plain = wavelet_kernel(lags, f, SignalVariation(peak_factor=1.0 + 1e-9), 600, dt)
    ringing = wavelet_kernel(lags, f, SignalVariation(ring_amplitude=0.3, ring_decay_periods=1.5), 600, dt)
    before, late = lags < 0.0, lags > 2.0
    assert np.allclose(plain[before], ringing[before])
    assert np.sum(ringing[late] ** 2) > 100.0 * np.sum(plain[late] ** 2)


def test_polarity_and_gain_scale_the_record() -> None:
    base = _echo(None)
    flipped = _echo(SignalVariation(polarity=-1.0, gain=2.0))
    assert np.allclose(flipped, -2.0 * base, atol=1e-3)


def test_a_broader_footprint_keeps_more_of_the_flanks() -> None:
    steep, broad = (np.abs(_echo(SignalVariation(footprint_power=p))).max(axis=1) for p in (3.0, 0.5))
    flank = np.argmin(np.abs(_line()[:, 0] - 1.3))
    assert broad[flank] / broad.max() > 1.5 * steep[flank] / steep.max()
    assert broad.max() == pytest.approx(steep.max(), rel=0.02)  # the apex ray is vertical: cos θ = 1


def test_varied_config_sets_the_height_and_noise_the_line_is_interpreted_with() -> None:
    gpr = varied_config(GprConfig(noise_mv=0.5), SignalVariation(antenna_height_m=0.0, noise_factor=4.0))
    assert gpr.antenna_height_m == 0.0 and gpr.noise_mv == pytest.approx(2.0)
    assert varied_config(GprConfig(), SignalVariation()) == GprConfig()
    assert math.isclose(varied_config(GprConfig(), SignalVariation()).antenna_height_m, 0.02)
