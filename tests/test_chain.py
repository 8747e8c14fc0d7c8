"""The interpretation chain stage by stage, on analytic data (synthetic_bscan: refracted times, Ricker, no sim)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from gprbot.config import GprConfig
from gprbot.gpr.bscan import BScan, SyntheticTarget, synthetic_bscan
from gprbot.gpr.chain.candidates import apex_candidates
from gprbot.gpr.chain.classify import _rebar_rows
from gprbot.gpr.chain.fit import CylinderFit, fit_cylinders
from gprbot.gpr.chain.geometry import cylinder_time, cylinder_time_gradient
from gprbot.gpr.chain.picks import Picks
from gprbot.gpr.chain.prepare import decimation_factor, noise_level, prepare
from gprbot.gpr.chain.run import SurveyHint, interpret
from gprbot.gpr.line_model import cylinder_times

V = 0.1
GPR = replace(GprConfig(), centre_frequency_mhz=900.0, antenna_height_m=0.02, tx_rx_offset_m=0.06)


def _line(targets: list[SyntheticTarget], *, noise: float = 0.01, n: int = 230) -> BScan:
    b = synthetic_bscan(targets, v_m_per_ns=V, centre_frequency_mhz=900.0, n_traces=n, spacing_m=0.01, samples=512,
                        dt_ns=0.025, t0_ns=1.0, antenna_height_m=GPR.antenna_height_m,
                        tx_rx_offset_m=GPR.tx_rx_offset_m, noise=noise, direct_wave=3.0)
    return replace(b, t0_ns=math.nan)  # as a file gives it: time zero unknown


@pytest.mark.parametrize(("height", "offset"), [(0.0, 0.05), (0.03, 0.08), (0.05, 0.1)])
def test_cylinder_time_matches_the_exact_refracted_time(height: float, offset: float) -> None:
    x = np.linspace(-0.5, 0.5, 41)
    exact = cylinder_times(x, 0.0, 0.2, 0.05, V, replace(GprConfig(), antenna_height_m=height, tx_rx_offset_m=offset))
    if height == 0.0:
        # A source in the surface: straight rays (the FDTD scenes at height 0 fit these, not head waves).
        px = x * (1 - 0.05 / np.hypot(x, 0.2))
        pz = 0.2 * (1 - 0.05 / np.hypot(x, 0.2))
        exact = (np.hypot(px - offset / 2, pz) + np.hypot(px + offset / 2, pz)) / V
    assert np.max(np.abs(cylinder_time(x, 0.0, 0.2, 0.05, V, height, offset) - exact)) < 1e-3


@pytest.mark.parametrize("height", [0.0, 0.03])
def test_cylinder_time_gradient_matches_finite_differences(height: float) -> None:
    x = np.linspace(-0.3, 0.3, 13)
    args = [0.02, 0.12, 0.03, 0.11]
    t, *grads = cylinder_time_gradient(x, *args, height, 0.05)
    assert np.allclose(t, cylinder_time(x, *args, height, 0.05))
    for k, g in enumerate(grads):
        hi, lo = list(args), list(args)
        hi[k] += 1e-6
        lo[k] -= 1e-6
        numeric = (cylinder_time(x, *hi, height, 0.05) - cylinder_time(x, *lo, height, 0.05)) / 2e-6
        assert np.max(np.abs(g - numeric)) < 0.01 * np.max(np.abs(numeric)) + 1e-6


def test_prepare_finds_time_zero_and_frequency_from_the_data() -> None:
    prep = prepare(_line([SyntheticTarget(1.0, 0.2, 0.02, 1.0)]), GPR)
    assert prep.t0_method == "direct-wave envelope peak"
    assert abs(prep.t0_ns - 1.0) < 0.05  # the synthetic's transmit instant
    assert 700.0 < prep.frequency_mhz < 1300.0  # a 900 MHz Ricker's spectrum (dewowed) peaks near it


def test_decimation_and_noise_level() -> None:
    assert decimation_factor(0.005, 1000.0) == 12  # 200 samples a period → about 16
    assert decimation_factor(0.06, 1000.0) == 1
    rng = np.random.default_rng(0)
    data = rng.normal(0.0, 1.0, (50, 400))
    data[:, :300] += 50.0 * rng.normal(0.0, 1.0, (50, 300))  # signal fills most windows
    assert 0.8 < noise_level(data) < 1.2


def test_candidates_mark_the_apex_not_the_flanks() -> None:
    prep = prepare(_line([SyntheticTarget(1.2, 0.25, 0.02, 1.0)]), GPR)
    cands = apex_candidates(prep)
    strongest = cands[0]
    assert abs(prep.x_m[strongest.column] - 1.2) <= 0.02
    # No candidate on the flanks of the one hyperbola (the others are its ringing, below the apex).
    assert all(abs(prep.x_m[c.column] - 1.2) <= 0.05 for c in cands if c.t_ns < strongest.t_ns + 0.5)


def test_batched_fit_recovers_cylinders_at_a_known_velocity() -> None:
    prep = prepare(_line([SyntheticTarget(1.0, 0.2, 0.02, 1.0)]), GPR)
    rng = np.random.default_rng(1)
    picks = []
    for x0, zc, r in [(0.6, 0.25, 0.04), (1.3, 0.15, 0.008)]:
        x = np.arange(x0 - 0.15, x0 + 0.151, 0.01)
        t = cylinder_time(x, x0, zc, r, V, GPR.antenna_height_m, GPR.tx_rx_offset_m) + rng.normal(0, 0.005, len(x))
        picks.append(Picks(apex_candidates(prep)[0], x, t, np.ones(len(x)), 15, 15))
    fits = fit_cylinders(prep, picks, V, free_velocity=False)
    for f, (x0, zc, r) in zip(fits, [(0.6, 0.25, 0.04), (1.3, 0.15, 0.008)], strict=True):
        assert f is not None
        assert abs(f.x0_m - x0) < 0.003 and abs(f.depth_m - zc) < 0.01 and abs(f.radius_m - r) < 0.01


def _fit(x0: float, top: float, radius: float = 0.006) -> CylinderFit:
    return CylinderFit(x0, top, radius, V, 0.001, 0.001, 0.002, 0.0, 0.01, 20)


def test_rebar_rows() -> None:
    row = [_fit(0.1 + 0.2 * k + 0.01 * (-1) ** k, 0.05) for k in range(5) if k != 3]  # one bar missing
    pipes = [_fit(0.45, 0.3, 0.05), _fit(0.8, 0.22, 0.04)]
    assert _rebar_rows(row + pipes) == {0, 1, 2, 3}
    irregular = [_fit(x, 0.05) for x in (0.1, 0.17, 0.5, 0.58)]
    assert _rebar_rows(irregular) == set()
    big_three = [_fit(0.1 + 0.2 * k, 0.05, 0.05) for k in range(3)]
    assert _rebar_rows(big_three) == set()  # three wide reflectors in a row may be pipes


def test_a_row_with_missing_bars_and_an_interloper_is_still_a_row() -> None:
    # A simulated survey line over a mesh at 16.8 cm: four bars not picked (one gap of three), and a crossing
    # of two neighbours' flanks halfway between the first two, at the same cover.
    xs = [0.109, 0.193, 0.276, 0.615, 0.945, 1.285, 1.452, 1.618]
    fits = [_fit(x, 0.055, 0.0) for x in xs]
    assert _rebar_rows(fits) == {0, 2, 3, 4, 5, 6, 7}
    sparse = [_fit(x, 0.12) for x in (0.1, 0.3, 1.2, 1.4)]  # two pairs off one lattice: not a mesh
    assert _rebar_rows(sparse) == set()


def test_two_thin_reflectors_at_a_meshs_cover_and_spacing_are_bars() -> None:
    assert _rebar_rows([_fit(0.25, 0.045), _fit(0.54, 0.045)]) == {0, 1}  # a short line over a mesh
    assert _rebar_rows([_fit(0.25, 0.045), _fit(0.75, 0.045)]) == set()  # farther apart than a mesh's bars
    assert _rebar_rows([_fit(0.25, 0.2), _fit(0.54, 0.2)]) == set()  # two pipes at one depth
    assert _rebar_rows([_fit(0.25, 0.045, 0.05), _fit(0.54, 0.045, 0.05)]) == set()  # wide: pipes


def test_interpret_finds_pipes_and_a_rebar_row_at_a_given_velocity() -> None:
    targets = [SyntheticTarget(0.55, 0.25, 0.03, 1.0), SyntheticTarget(1.45, 0.3, 0.05, 1.0)]
    targets += [SyntheticTarget(0.1 + 0.3 * k, 0.07, 0.006, 0.5) for k in range(7)]
    result = interpret(_line(targets), GPR, V)
    pipes = [(d.x_m, d.depth_m) for d in result.pipes]
    for x0, zc in [(0.55, 0.25), (1.45, 0.3)]:
        assert any(abs(x - x0) < 0.02 and abs(z - zc) < 0.02 for x, z in pipes), (x0, pipes)
    bars = [d.x_m for d in result.rebars]
    assert sum(any(abs(b - (0.1 + 0.3 * k)) < 0.02 for b in bars) for k in range(7)) >= 5
    assert result.velocity_source == "given"
    assert result.section.mask.any() and len(result.section.rebars) == len(result.rebars)


def test_interpret_without_hyperbolas_says_the_velocity_was_not_estimated() -> None:
    result = interpret(_line([], noise=0.01), GPR)
    assert result.detections == ()
    assert result.velocity_source == "fallback"
    assert any("velocity not estimated" in n for n in result.notes)


def test_a_row_with_a_line_end_artefact_is_still_a_row() -> None:
    row = [_fit(0.29 + 0.15 * k, 0.044, 0.0) for k in range(4)]
    artefact = [_fit(0.048, 0.048, 0.0)]  # 1.6 spacings before the first bar: no bar there
    assert _rebar_rows(artefact + row) == {1, 2, 3, 4}


def test_echo_spots_ringing_multiple_and_crossing_flanks() -> None:
    from gprbot.gpr.chain.spots import Spot, is_echo_spot

    wavelength = 0.1
    primary = [(0.5, 0.1, 0.02)]
    assert is_echo_spot(Spot(0.5, 0.16, 1.0, 1.0, 0), primary, wavelength)  # ringing right under it
    assert is_echo_spot(Spot(0.505, 0.2, 1.0, 1.0, 0), primary, wavelength)  # twice its depth
    assert not is_echo_spot(Spot(0.7, 0.16, 1.0, 1.0, 0), primary, wavelength)  # beside it: a target
    pair = [(0.4, 0.2, 0.0), (0.5, 0.2, 0.0)]
    assert is_echo_spot(Spot(0.45, 0.25, 1.0, 1.0, 0), pair, wavelength)  # under two crossing flanks
    assert not is_echo_spot(Spot(0.45, 0.2, 1.0, 1.0, 0), pair, wavelength)  # between them at their depth


def test_a_deep_spot_is_judged_against_the_image_below_the_direct_wave() -> None:
    """The direct wave's row migrates to the brightest cell by far; a deep focus is a fraction of a per cent of
    it (the SU trench line: 0.2-0.7 %) and must still be a spot: the share is of the cells a target may be in."""
    from gprbot.gpr.chain.spots import find_spots

    prep = prepare(_line([SyntheticTarget(1.0, 0.2, 0.02, 1.0)]), GPR)
    z = np.arange(0.0, 0.8, 0.0025)
    xx, zz = np.meshgrid(prep.x_m, z)
    image = 1e-4 + np.exp(-((xx - 1.2) ** 2 + (zz - 0.5) ** 2) / (2 * 0.01**2))  # a compact focus, peak 1
    image[0, :] = 1000.0  # the direct wave's residual at the surface, excluded as a target
    spots = find_spots(prep, image.astype(np.float32), z, V)
    assert any(abs(s.x_m - 1.2) < 0.01 and abs(s.top_m - 0.5) < 0.01 for s in spots)


def test_velocity_voters_leave_out_echoes() -> None:
    from gprbot.gpr.chain.velocity import _echo_of

    assert _echo_of(0.40, 10.9, 0.40, 3.25)  # a water pipe's bottom, right under its top
    assert _echo_of(0.33, 7.12, 0.375, 3.77)  # the surface multiple, pulled 4.5 cm aside
    assert not _echo_of(0.60, 7.0, 0.40, 3.5)  # a neighbour at twice the time, 20 cm away
    assert not _echo_of(0.40, 3.0, 0.40, 3.5)  # earlier than the stronger one: not its echo


def test_smooth_residuals_inflate_the_covariance_white_ones_do_not() -> None:
    from gprbot.gpr.chain.fit import correlation_inflation

    rng = np.random.default_rng(3)
    assert correlation_inflation(rng.normal(0.0, 1.0, 400)) < 1.3
    smooth = np.sin(np.linspace(0.0, 3.0, 40))  # a model error: one slow curve along the flank
    assert correlation_inflation(smooth) > 10.0
    assert correlation_inflation(np.zeros(10)) == 1.0


def test_a_radius_the_curve_does_not_measure_puts_the_centre_halfway() -> None:
    from gprbot.gpr.chain.classify import reported_radius

    measured = CylinderFit(0.5, 0.2, 0.04, V, 0.001, 0.001, 0.004, 0.0, 0.01, 30)
    assert reported_radius(measured) == (0.04, 0.004, True)
    loose = replace(measured, sigma_radius_m=0.015)
    radius, sigma, supported = reported_radius(loose)
    assert not supported and radius == pytest.approx(0.02) and sigma == pytest.approx(0.02)
    # A radius the fit put at 0 with a wide error is reported with that error, not as "0 ± 0".
    at_zero = replace(measured, radius_m=0.0, sigma_radius_m=0.011)
    assert reported_radius(at_zero) == (0.0, 0.011, False)
    assert reported_radius(replace(measured, sigma_radius_m=0.03))[1] == pytest.approx(0.03)


def test_a_line_shorter_than_its_hyperbola_keeps_the_apex() -> None:
    # 12 cm of line over a bar 9 cm down (gprMax's 2D example): every trace sees nearly the same apex,
    # so the median trace holds it, and subtracting that all the way down leaves nothing to detect.
    v = 0.1224
    b = synthetic_bscan([SyntheticTarget(0.06, 0.09, 0.01, 1.0)], v_m_per_ns=v, centre_frequency_mhz=1500.0,
                        n_traces=40, spacing_m=0.003, samples=400, dt_ns=0.01, t0_ns=0.5,
                        antenna_height_m=0.0, tx_rx_offset_m=0.04, noise=0.005, direct_wave=3.0)
    gpr = replace(GprConfig(), centre_frequency_mhz=1500.0, antenna_height_m=0.0, tx_rx_offset_m=0.04)
    found = interpret(replace(b, t0_ns=math.nan), gpr, v).detections
    assert any(abs(d.x_m - 0.06) < 0.01 and abs(d.fit.top_m - 0.08) < 0.01 for d in found), found


def test_an_apex_must_be_earliest_on_both_flanks() -> None:
    from gprbot.gpr.chain.classify import descends_on_both_flanks

    prep = prepare(_line([SyntheticTarget(1.0, 0.2, 0.02, 1.0)]), GPR)
    fit = CylinderFit(1.0, 0.2, 0.0, V, 0.001, 0.001, 0.002, 0.0, 0.01, 21)
    x = np.arange(0.9, 1.101, 0.01)
    hyperbola = cylinder_time(x, 1.0, 0.2, 0.0, V, GPR.antenna_height_m, GPR.tx_rx_offset_m)
    cand = apex_candidates(prep)[0]
    assert descends_on_both_flanks(prep, Picks(cand, x, hyperbola, np.ones(len(x)), 10, 10), fit)
    kink = np.where(x < 1.0, hyperbola[10], hyperbola)  # a layer's kink: level to the left, dipping to the right
    assert not descends_on_both_flanks(prep, Picks(cand, x, kink, np.ones(len(x)), 10, 10), fit)


def test_a_bright_echo_under_a_pipe_does_not_vote_for_the_velocity() -> None:
    from types import SimpleNamespace

    from gprbot.gpr.chain.velocity import _primaries

    prep = SimpleNamespace(x_m=np.arange(100) * 0.01)

    def reflector(column: int, t_ns: float, snr: float) -> SimpleNamespace:
        return SimpleNamespace(candidate=SimpleNamespace(column=column, t_ns=t_ns, snr=snr))

    top, bottom, other = reflector(40, 3.0, 20.0), reflector(41, 9.0, 60.0), reflector(80, 5.0, 30.0)
    # Strongest first, as the voters are ranked: the water pipe's bottom echo leads, yet it is the echo.
    kept = _primaries(prep, [bottom, other, top])  # type: ignore[arg-type]
    assert kept == [other, top]


def test_refracted_leg_is_fermats_minimum_even_near_grazing() -> None:
    from gprbot.gpr.chain.geometry import leg_time
    from gprbot.gpr.traveltime import C_M_PER_NS

    D, d = np.array([0.0, 0.05, 0.3, 0.8, 1.5]), np.array([0.02, 0.1, 0.05, 0.02, 0.3])
    for h in (0.005, 0.03, 0.06):
        for v in (0.05, 0.12, 0.28):
            a = np.linspace(0.0, 1.0, 200001)[:, None] * D[None, :]  # every entry point, 5 µm apart at most
            brute = (np.sqrt(h * h + a * a) / C_M_PER_NS + np.sqrt(d * d + (D - a) ** 2) / v).min(axis=0)
            assert np.max(np.abs(leg_time(h, D, d, v) - brute)) < 1e-3  # ns: under a picosecond


def test_the_apex_test_of_all_events_at_once_matches_its_definition_event_by_event() -> None:
    from gprbot.gpr.chain.candidates import _earliest

    def one(events: np.ndarray, col: int, row: int, k: int, half: int, tolerance: float) -> bool:
        for side in (col - k, col + k):
            if 0 <= side < events.shape[0]:
                lo = max(0, row - half)
                near = np.flatnonzero(events[side, lo:row + half + 1]) + lo
                if len(near) and near[np.argmin(np.abs(near - row))] < row - tolerance:
                    return False
        return True

    rng = np.random.default_rng(0)
    for _ in range(100):
        events = rng.random((int(rng.integers(3, 40)), int(rng.integers(5, 80)))) < rng.uniform(0.01, 0.3)
        cols, rows = np.nonzero(events)
        k, half, tol = int(rng.integers(1, 4)), int(rng.integers(1, 6)), float(rng.uniform(0.0, 3.0))
        expected = [one(events, int(c), int(r), k, half, tol) for c, r in zip(cols, rows, strict=True)]
        assert list(_earliest(events, cols, rows, k, half, tol)) == expected


def test_a_surveys_crossing_hint_puts_an_oblique_pipe_at_its_depth() -> None:
    # Along a line crossed at angle θ, a pipe's hyperbola is the right-angle one of a pipe 1/sin θ deeper in a
    # host 1/sin θ faster: synthesise that, interpret at the host's velocity with the survey's hint.
    sin = 0.7
    b = synthetic_bscan([SyntheticTarget(1.0, 0.25 / sin, 0.03 / sin, 1.0)], v_m_per_ns=V / sin,
                        centre_frequency_mhz=900.0, n_traces=200, spacing_m=0.01, samples=512, dt_ns=0.025, t0_ns=1.0,
                        antenna_height_m=0.0, tx_rx_offset_m=0.02, noise=0.01, direct_wave=3.0)
    gpr = replace(GPR, antenna_height_m=0.0, tx_rx_offset_m=0.02)
    hinted = interpret(b, gpr, V, hint_at=lambda x: SurveyHint(sin_cross=sin))
    pipe = min(hinted.pipes, key=lambda d: abs(d.x_m - 1.0))
    assert abs(pipe.x_m - 1.0) < 0.02 and abs(pipe.fit.top_m - 0.22) < 0.015 and pipe.sin_cross == pytest.approx(sin)
    square = interpret(b, gpr, V)  # the same curve taken at right angles: not where the pipe is
    assert all(abs(d.depth_m - 0.25) > 0.03 for d in square.pipes if abs(d.x_m - 1.0) < 0.05)


def test_a_pipes_radius_is_the_surveys_where_it_has_one() -> None:
    b = _line([SyntheticTarget(0.8, 0.2, 0.004, 1.0)], noise=0.1)  # a thin bar in noise: its radius is not measured
    own = interpret(b, GPR, V)
    assert own.pipes and not any(d.radius_supported for d in own.pipes)
    held = interpret(b, GPR, V, hint_at=lambda x: SurveyHint(radius_m=0.05))
    for d in held.pipes:
        assert d.radius_m == 0.05 and d.depth_m == pytest.approx(d.fit.top_m + 0.05)


def test_a_known_top_gives_the_velocity_its_apex_time_needs() -> None:
    from gprbot.gpr.chain.calibrate import KnownTop, velocity_for

    line = _line([SyntheticTarget(0.8, 0.25, 0.03, 1.0), SyntheticTarget(0.8, 0.45, 0.03, 0.4)])  # and an echo
    result = interpret(line, GPR, known_tops=[KnownTop(0.8, 0.22)])
    assert result.velocity_source == "calibrated" and result.velocity == pytest.approx(V, rel=0.03)
    prep = result.prepared
    t = float(cylinder_time(np.array([0.0]), 0.0, 0.22, 0.0, V, GPR.antenna_height_m, GPR.tx_rx_offset_m)[0])
    assert velocity_for(prep, t, 0.22) == pytest.approx(V, rel=1e-6)
    assert velocity_for(prep, 1e-3, 0.22) is None  # no velocity in bounds puts 22 cm that early


def test_two_known_tops_fix_the_velocity_and_time_zero_where_one_cannot() -> None:
    from gprbot.gpr.chain.calibrate import KnownTop

    late = replace(_line([SyntheticTarget(0.5, 0.12, 0.01, 1.0), SyntheticTarget(1.5, 0.32, 0.01, 1.0)]),
                   t0_ns=1.0 - 0.15)  # time zero given 0.15 ns early: every apex reads late
    shallow, deep = KnownTop(0.5, 0.11), KnownTop(1.5, 0.31)
    one = interpret(late, GPR, known_tops=[shallow])
    assert one.velocity < 0.95 * V  # a late apex reads as a slow velocity
    two = interpret(late, GPR, known_tops=[shallow, deep])
    assert two.velocity_source == "calibrated" and "2 known tops" in two.velocity_method
    assert two.velocity == pytest.approx(V, rel=0.02)
    assert two.prepared.t0_ns == pytest.approx(1.0, abs=0.03) and "moved" in two.prepared.t0_method
    pipes = sorted((d.x_m, d.fit.top_m) for d in two.pipes)
    assert [round(x, 1) for x, _ in pipes] == [0.5, 1.5]
    assert all(abs(top - want) <= 0.005 for (_, top), want in zip(pipes, (0.11, 0.31), strict=True))
