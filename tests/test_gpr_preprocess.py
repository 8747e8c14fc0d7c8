"""Preprocessing: dewow, time zero, median background removal, gain, idempotence, input checks."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from gprbot.config import GprConfig
from gprbot.errors import InterpretationError
from gprbot.gpr.bscan import BScan, SyntheticTarget, along_track_distance, synthetic_bscan
from gprbot.gpr.preprocess import (
    apply_gain,
    dewow,
    find_time_zero,
    preprocess,
    remove_background,
)
from gprbot.gpr.traveltime import C_M_PER_NS, velocity_from_eps
from gprbot.gpr.wavelet import ricker

GPR = GprConfig()
DT = GPR.dt_ns


def _line(**kwargs: object) -> BScan:
    args: dict[str, object] = {
        "v_m_per_ns": velocity_from_eps(6.25), "centre_frequency_mhz": 900.0, "n_traces": 120,
        "spacing_m": 0.01, "samples": 512, "dt_ns": DT, "t0_ns": 1.0, "antenna_height_m": 0.02,
        "tx_rx_offset_m": 0.05,
    }
    args.update(kwargs)
    return synthetic_bscan(**args)  # type: ignore[arg-type]


def test_dewow_removes_dc_and_ramp_but_keeps_the_pulse() -> None:
    t = np.arange(512) * DT
    pulse = ricker(t - 5.0, 900.0)
    wow = 40.0 + 8.0 * t  # DC offset plus a slow ramp, 10× the pulse
    out = dewow((pulse + wow)[None, :], DT, 900.0)[0]
    inner = slice(60, 450)  # away from the trace ends, where a running mean sees only one side
    residual = out[inner] - pulse[inner]
    assert np.max(np.abs(residual)) < 0.2  # was up to 120 before
    assert abs(int(np.argmax(out[inner])) - int(np.argmax(pulse[inner]))) <= 1


@pytest.mark.parametrize("t0_ns", [0.8, 1.0, 1.37, 2.5])
def test_time_zero_found_from_the_direct_wave(t0_ns: float) -> None:
    offset = 0.05
    t = np.arange(512) * DT - t0_ns
    direct = 50.0 * ricker(t - offset / C_M_PER_NS, 900.0)
    traces = np.tile(direct, (30, 1)) + np.random.default_rng(1).normal(0.0, 0.2, (30, 512))
    assert find_time_zero(traces, DT, tx_rx_offset_m=offset) == pytest.approx(t0_ns, abs=0.01)


def test_median_background_kills_a_flat_band_and_keeps_the_hyperbola() -> None:
    pipe = [SyntheticTarget(0.6, 0.15, 0.01, amplitude=1.0)]
    with_band = _line(targets=pipe, flat_depths_m=(0.30,), flat_amplitude=2.0)
    pipe_only = _line(targets=pipe)
    along = with_band.along_track_m()
    out = remove_background(with_band.data, along, spacing_m=0.01)
    # The band is the same in every trace, so the median takes all of it and nothing else.
    np.testing.assert_allclose(out, remove_background(pipe_only.data, along, spacing_m=0.01), atol=2e-3)
    apex = np.unravel_index(np.argmax(np.abs(pipe_only.data)), pipe_only.data.shape)
    assert abs(out[apex]) > 0.9 * abs(pipe_only.data[apex])


def test_median_leaves_no_ghost_of_a_strong_pipe_where_mean_does() -> None:
    b = _line(targets=[SyntheticTarget(0.3, 0.12, 0.03, amplitude=5.0)], footprint_power=3.0)
    along = b.along_track_m()
    median_residual = remove_background(b.data, along, spacing_m=0.01)
    mean_residual = b.data - b.data.mean(axis=0)
    far = along > 0.9  # traces the pipe's echo does not reach (its footprint is ~0.3 m wide)
    assert np.abs(b.data[far]).max() < 0.05
    assert np.abs(median_residual[far]).max() < 0.05
    assert np.abs(mean_residual[far]).max() > 0.3  # the mean smears the pipe into every trace


def test_gain_grows_with_time_and_is_capped() -> None:
    ones = np.ones((2, 512), dtype=np.float32)
    g = apply_gain(ones, DT, 1.0, power=1.0, max_gain=5.0)[0]
    assert g[0] == pytest.approx(1.0)
    assert np.all(np.diff(g) >= 0)
    assert g.max() == pytest.approx(5.0)


def test_preprocess_estimates_unknown_time_zero_and_is_idempotent() -> None:
    b = replace(_line(targets=[SyntheticTarget(0.6, 0.15, 0.02)], direct_wave=20.0), t0_ns=math.nan)
    once = preprocess(b, GPR)
    assert once.t0_ns == pytest.approx(1.0, abs=0.05)
    twice = preprocess(once, GPR)
    np.testing.assert_array_equal(once.data, twice.data)
    assert once.processing == twice.processing


def test_along_track_of_a_jittery_straight_line_is_not_stretched() -> None:
    rng = np.random.default_rng(3)
    n = 400
    positions = np.zeros((n, 3))
    positions[:, 0] = np.linspace(0.0, 2.0, n)
    positions[:, :2] += rng.normal(0.0, 0.003, (n, 2))
    along = along_track_distance(positions)
    assert along[-1] == pytest.approx(2.0, abs=0.01)  # cumulative distance would give ~2.7 m


@pytest.mark.parametrize("shape", [(0, 512), (3, 512), (50, 4)])
def test_empty_or_too_short_bscan_is_refused(shape: tuple[int, int]) -> None:
    positions = np.zeros((shape[0], 3))
    positions[:, 0] = np.arange(shape[0]) * 0.01
    b = BScan(np.zeros(shape, np.float32), DT, 1.0, positions, np.zeros(shape[0]))
    with pytest.raises(InterpretationError, match=r"trace|sample|empty"):
        preprocess(b, GPR)


def test_standing_still_is_refused() -> None:
    b = BScan(np.ones((20, 64), np.float32), DT, 1.0, np.zeros((20, 3)), np.zeros(20))
    with pytest.raises(InterpretationError, match="did not move"):
        preprocess(b, GPR)
