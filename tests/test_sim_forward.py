"""The GPR forward model against travel-time physics, and the ground-truth helpers against geometry."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gprbot.config import GprConfig
from gprbot.gpr.traveltime import C_M_PER_NS, refracted_leg_time, two_way_time, velocity_from_eps
from gprbot.gpr.wavelet import ricker
from gprbot.sim.forward import simulate_bscan
from gprbot.sim.reflectors import FILL_OPTICS
from gprbot.sim.scene import Fill, Pipe, Scene, Slab, load_scene
from gprbot.sim.truth import cross_section_mask, sample_pipe_interiors

SLAB = Slab((2.4, 1.2), (-0.2, -0.1), 0.45, 6.25, 15.0)
V = velocity_from_eps(SLAB.eps_r)
LINE_Y = 0.4


def _scene(*pipes: Pipe) -> Scene:
    return Scene("test", "", SLAB, pipes, None, None)


def _straight(fill: Fill, depth: float, radius: float, x: float = 1.0, angle_deg: float = 90.0) -> Pipe:
    """A pipe through (x, LINE_Y) crossing the survey lines at angle_deg."""
    d = np.array([math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))]) * 0.5
    ends = [[x - d[0], LINE_Y - d[1], -depth], [x + d[0], LINE_Y + d[1], -depth]]
    return Pipe(f"{fill}-{depth}", np.array(ends), radius, fill)


def _line(x0: float = 0.5, x1: float = 1.5, step: float = 0.005) -> np.ndarray:
    x = np.arange(x0, x1 + step / 2, step)
    return np.stack([x, np.full_like(x, LINE_Y)], axis=1)


def _response(scene: Scene, mid: np.ndarray, gpr: GprConfig) -> np.ndarray:
    """The pipes' echoes alone: the same survey of the empty slab, same seed, subtracted."""
    full = simulate_bscan(scene, mid, gpr, np.random.default_rng(3)).astype(np.float64)
    empty = simulate_bscan(dataclasses.replace(scene, pipes=()), mid, gpr, np.random.default_rng(3))
    return full - empty


def _sample_of(t_ns: float, gpr: GprConfig) -> float:
    return (t_ns + gpr.pre_trigger_ns) / gpr.dt_ns


def test_an_antenna_on_the_surface_sends_straight_rays_and_one_above_it_refracted_ones() -> None:
    # On the surface Fermat's fastest path would run along it in the air (a weak lateral wave); the FDTD
    # scenes with a source at the surface follow the straight ray through the ground.
    horiz, depth = np.array([0.0, 0.1, 0.3]), np.array([0.1, 0.1, 0.1])
    on = refracted_leg_time(np.zeros(3), horiz, depth, V)
    assert np.allclose(on, np.hypot(horiz, depth) / V)
    up = refracted_leg_time(np.full(3, 0.02), horiz, depth, V)
    assert up[0] == pytest.approx(0.02 / C_M_PER_NS + 0.1 / V)
    assert np.all(up[1:] < 0.02 / C_M_PER_NS + np.hypot(horiz[1:], depth[1:]) / V)  # bent: faster than straight


def test_ricker_peak_zero_crossings_and_spectrum() -> None:
    f = 900.0
    assert ricker(np.array([0.0]), f)[0] == pytest.approx(1.0)
    zero = 1.0 / (math.pi * f * 1e-3 * math.sqrt(2.0))
    assert np.allclose(ricker(np.array([-zero, zero]), f), 0.0, atol=1e-12)
    t = np.arange(-20.0, 20.0, 0.005)
    spectrum = np.abs(np.fft.rfft(ricker(t, f)))
    peak_mhz = np.fft.rfftfreq(len(t), 0.005)[np.argmax(spectrum)] * 1e3
    assert peak_mhz == pytest.approx(f, abs=30.0)


@pytest.mark.parametrize("angle_deg", [90.0, 55.0])
def test_metal_apex_at_two_way_time_and_at_the_pipe(angle_deg: float) -> None:
    gpr = GprConfig()
    mid = _line()
    pipe = _straight("metal", depth=0.15, radius=0.03, angle_deg=angle_deg)
    echo = _response(_scene(pipe), mid, gpr)
    trace, sample = np.unravel_index(np.argmin(echo), echo.shape)
    assert mid[trace, 0] == pytest.approx(1.0, abs=0.005)  # one trace spacing
    top = np.array([1.0, LINE_Y, -0.15 + 0.03])
    t = float(
        two_way_time(np.array([1.0, LINE_Y]), top, V, gpr.antenna_height_m, gpr.tx_rx_offset_m, np.array([1.0, 0.0]))
    )
    assert abs(sample - _sample_of(t, gpr)) <= 1.0
    # the straight-ray estimate 2 d / v misses by the air legs and refraction: the model must not equal it
    assert abs(sample - _sample_of(2 * 0.12 / V, gpr)) > 3.0
    assert -600.0 < echo.min() < -150.0  # "a few hundred mV"


def test_polarity_metal_negative_pvc_air_positive_pvc_water_flipped_and_weak() -> None:
    gpr = GprConfig()
    apex = np.array([[1.0, LINE_Y]])
    peaks = {}
    for fill in ("metal", "pvc-air", "pvc-water"):
        echo = _response(_scene(_straight(fill, 0.18, 0.04)), apex, gpr)[0]
        peaks[fill] = echo[np.argmax(np.abs(echo))]
    assert peaks["metal"] < 0 < peaks["pvc-air"]
    assert peaks["pvc-water"] < 0
    assert abs(peaks["pvc-water"]) < abs(peaks["pvc-air"]) < abs(peaks["metal"])


def test_pvc_air_shows_top_and_inner_bottom_with_the_round_trip_delay() -> None:
    gpr = GprConfig(centre_frequency_mhz=2600.0)  # short wavelet: the two echoes separate
    radius, depth = 0.08, 0.25
    echo = _response(_scene(_straight("pvc-air", depth, radius)), np.array([[1.0, LINE_Y]]), gpr)[0]
    top = np.array([1.0, LINE_Y, -depth + radius])
    t_top = float(
        two_way_time(np.array([1.0, LINE_Y]), top, V, gpr.antenna_height_m, gpr.tx_rx_offset_m, np.array([1.0, 0.0]))
    )
    delay = 4.0 * radius / C_M_PER_NS  # down and up the air-filled diameter
    assert abs(int(np.argmax(echo)) - _sample_of(t_top, gpr)) <= 1.0
    window = slice(int(_sample_of(t_top + 0.6, gpr)), int(_sample_of(t_top + 1.8, gpr)))
    bottom = window.start + int(np.argmin(echo[window]))
    assert abs(bottom - _sample_of(t_top + delay, gpr)) <= 1.0
    # Fresnel: top r·w = (n - 1)/(n + 1)·w; bottom -r (1 - r²)·w² after crossing the top wall twice
    r = (math.sqrt(SLAB.eps_r) - 1.0) / (math.sqrt(SLAB.eps_r) + 1.0)
    w = FILL_OPTICS["pvc-air"].wall_factor
    assert echo[bottom] / echo.max() == pytest.approx(-(1.0 - r * r) * w, rel=0.1)


def test_amplitude_falls_with_depth_and_along_the_flanks() -> None:
    gpr = GprConfig()
    mid = _line(0.7, 1.3, 0.01)
    apex_amplitudes = []
    for depth in (0.10, 0.20, 0.30):
        echo = np.abs(_response(_scene(_straight("metal", depth, 0.03)), mid, gpr))
        per_trace = echo.max(axis=1)
        apex_amplitudes.append(per_trace.max())
        assert per_trace[np.argmin(np.abs(mid[:, 0] - 1.25))] < 0.35 * per_trace.max()
    assert apex_amplitudes[0] > apex_amplitudes[1] > apex_amplitudes[2] > 5.0


def test_direct_wave_wow_and_slab_bottom_of_an_empty_slab() -> None:
    gpr = GprConfig(noise_mv=0.0)
    trace = simulate_bscan(_scene(), np.array([[1.0, LINE_Y]]), gpr, np.random.default_rng(0))[0]
    assert 700.0 < trace.max() < 1400.0
    assert abs(int(np.argmax(trace)) - _sample_of(gpr.tx_rx_offset_m / C_M_PER_NS, gpr)) < 0.5 / gpr.dt_ns
    t = np.arange(gpr.samples) * gpr.dt_ns - gpr.pre_trigger_ns
    late = (t > 3.0) & (t < 6.0)
    assert trace[late].mean() > 20.0  # the receiver's low-frequency drift ("wow")
    # the slab bottom alone: minus the same slab made too thick for its bottom to fall in the window
    thick = dataclasses.replace(_scene(), slab=dataclasses.replace(SLAB, thickness_m=1.5))
    bottom = trace - simulate_bscan(thick, np.array([[1.0, LINE_Y]]), gpr, np.random.default_rng(0))[0]
    bottom_point = np.array([1.0, LINE_Y, -SLAB.thickness_m])
    t_bottom = float(two_way_time(np.array([1.0, LINE_Y]), bottom_point, V, 0.02, 0.05, np.array([1.0, 0.0])))
    assert abs(int(np.argmin(bottom)) - _sample_of(t_bottom, gpr)) <= 1.0  # concrete onto moist soil: negative
    assert 2.0 < -bottom.min() < 50.0
    # a suspended slab: concrete onto air reflects with the opposite sign and more strongly
    over_air = dataclasses.replace(_scene(), slab=dataclasses.replace(SLAB, below_eps_r=1.0))
    air = simulate_bscan(over_air, np.array([[1.0, LINE_Y]]), gpr, np.random.default_rng(0))[0]
    air_bottom = air - simulate_bscan(thick, np.array([[1.0, LINE_Y]]), gpr, np.random.default_rng(0))[0]
    assert abs(int(np.argmax(air_bottom)) - _sample_of(t_bottom, gpr)) <= 1.0
    n = math.sqrt(SLAB.eps_r)  # Fresnel: (n - 1)/(n + 1) onto air against (n - √15)/(n + √15) onto soil
    ratio = ((n - 1.0) / (n + 1.0)) / ((math.sqrt(15.0) - n) / (math.sqrt(15.0) + n))
    assert air_bottom.max() / -bottom.min() == pytest.approx(ratio, rel=0.05)


def test_rebar_bars_appear_at_their_positions() -> None:
    scene = load_scene("cluttered_rebar")
    gpr = GprConfig()
    mid = _line(0.0, 2.0, 0.01)
    bare = dataclasses.replace(scene, rebar=None)
    echo = simulate_bscan(scene, mid, gpr, np.random.default_rng(1)) - simulate_bscan(
        bare, mid, gpr, np.random.default_rng(1)
    )
    y_bars = [b for b in scene.rebar_bars() if b.name.startswith("rebar_y")]
    top = 0.05
    t = float(
        two_way_time(
            np.array([0.0, 0.0]),
            np.array([0.0, 0.0, -top]),
            velocity_from_eps(scene.slab.eps_r),
            0.02,
            0.05,
            np.array([1.0, 0.0]),
        )
    )
    row = echo[:, round(_sample_of(t, gpr))]
    for bar in y_bars:
        x = float(bar.points[0, 0])
        if 0.05 < x < 1.95:
            near = np.abs(mid[:, 0] - x) < 0.08
            assert mid[near][np.argmin(row[near]), 0] == pytest.approx(x, abs=0.011)


def test_deterministic_for_a_fixed_seed_and_shape() -> None:
    scene, gpr, mid = load_scene("cluttered_rebar"), GprConfig(samples=256), _line(0.0, 2.0, 0.02)
    a = simulate_bscan(scene, mid, gpr, np.random.default_rng(5))
    b = simulate_bscan(scene, mid, gpr, np.random.default_rng(5))
    c = simulate_bscan(scene, mid, gpr, np.random.default_rng(6))
    assert a.shape == (len(mid), 256) and a.dtype == np.float32 and np.all(np.isfinite(a))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert simulate_bscan(scene, mid[:0], gpr, np.random.default_rng(5)).shape == (0, 256)
    with pytest.raises(ValueError, match="mid_xy"):
        simulate_bscan(scene, mid[:, 0], gpr, np.random.default_rng(5))


def test_mask_of_a_perpendicular_pipe_is_a_disk() -> None:
    radius, depth, step = 0.04, 0.2, 0.001
    x = np.arange(0.8, 1.2, step)
    z = np.arange(0.0, 0.4, step)
    mask = cross_section_mask(_scene(_straight("pvc-air", depth, radius)), np.stack([x, np.full_like(x, LINE_Y)], 1), z)
    assert mask.sum() * step * step == pytest.approx(math.pi * radius**2, rel=0.1)
    rows, cols = np.nonzero(mask)
    assert z[rows].mean() == pytest.approx(depth, abs=step) and x[cols].mean() == pytest.approx(1.0, abs=step)
    assert np.ptp(x[cols]) == pytest.approx(2 * radius, abs=2 * step)


def test_mask_of_an_oblique_pipe_is_a_widened_ellipse() -> None:
    radius, depth, step, angle = 0.04, 0.2, 0.001, 50.0
    x = np.arange(0.7, 1.3, step)
    z = np.arange(0.0, 0.4, step)
    scene = _scene(_straight("metal", depth, radius, angle_deg=angle))
    mask = cross_section_mask(scene, np.stack([x, np.full_like(x, LINE_Y)], 1), z)
    widening = 1.0 / math.cos(math.radians(90.0 - angle))
    assert mask.sum() * step * step == pytest.approx(math.pi * radius**2 * widening, rel=0.1)
    cols = np.nonzero(mask)[1]
    assert np.ptp(x[cols]) == pytest.approx(2 * radius * widening, abs=2 * step)
    assert np.ptp(z[np.nonzero(mask)[0]]) == pytest.approx(2 * radius, abs=2 * step)


def test_mask_excludes_rebar_and_clutter() -> None:
    scene = load_scene("cluttered_rebar")
    x = np.arange(0.0, 2.0, 0.005)
    mask = cross_section_mask(scene, np.stack([x, np.full_like(x, 0.45)], 1), np.arange(0.0, 0.12, 0.002))
    assert not mask.any()


@pytest.mark.parametrize("name", ["paper_slab", "bend_tee"])
def test_interior_samples_lie_inside_their_pipes_and_are_uniform(name: str) -> None:
    scene = load_scene(name)
    region = (0.0, 2.0, 0.0, 0.9)
    points, owner = sample_pipe_interiors(scene, 6000, np.random.default_rng(0), region)
    assert points.shape == (6000, 3) and owner.shape == (6000,)
    assert np.all((points[:, 0] >= 0.0) & (points[:, 0] <= 2.0) & (points[:, 1] >= 0.0) & (points[:, 1] <= 0.9))
    for index, pipe in enumerate(scene.pipes):
        mine = points[owner == index]
        distance = np.min([_distance_to_segment(mine, a, b) for a, b in pipe.segments()], axis=0)
        assert np.all(distance <= pipe.radius_m + 1e-9), pipe.name
    if name == "paper_slab":  # straight pipes across the whole region: shares follow the cross-sections
        areas = np.array([math.pi * p.radius_m**2 for p in scene.pipes])
        shares = np.bincount(owner, minlength=len(areas)) / len(owner)
        assert shares == pytest.approx(areas / areas.sum(), abs=0.02)


def _distance_to_segment(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    s = np.clip((points - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(points - (a + s[:, None] * ab), axis=1)
