"""Interpretation: cylinder fits, detections, the filled mask, PNGs, the real SIR-3000 file."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from gprbot.config import GprConfig, InterpretationConfig
from gprbot.errors import InterpretationError
from gprbot.gpr.bscan import BScan, SyntheticTarget, bscan_from_dzt, synthetic_bscan
from gprbot.gpr.hyperbola import hyperbolas_of_line
from gprbot.gpr.interpret import fit_cylinder, interpret_bscan
from gprbot.gpr.line_model import prepare_line
from gprbot.gpr.render import write_bscan_png, write_cross_section_png
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.sim.forward import simulate_bscan
from gprbot.sim.scene import Pipe, Scene, Slab

CFG = InterpretationConfig()
GPR = GprConfig()
V = velocity_from_eps(6.25)


def _line(targets: list[SyntheticTarget], v: float = V) -> BScan:
    return synthetic_bscan(
        targets, v_m_per_ns=v, centre_frequency_mhz=900.0, n_traces=170, spacing_m=0.01, samples=512,
        dt_ns=GPR.dt_ns, t0_ns=GPR.pre_trigger_ns, antenna_height_m=GPR.antenna_height_m,
        tx_rx_offset_m=GPR.tx_rx_offset_m, noise=0.005, direct_wave=2.0, footprint_power=3.0,
        rng=np.random.default_rng(11),
    )


def test_cylinder_fit_recovers_centre_and_radius() -> None:
    truth = SyntheticTarget(0.8, 0.20, 0.03, amplitude=-1.0)
    line = prepare_line(_line([truth]), GPR)
    (h,) = hyperbolas_of_line(line, V, GPR, CFG)
    fit = fit_cylinder(h.x_m, h.t_ns, V, GPR)
    assert fit.x0_m == pytest.approx(0.8, abs=0.005)
    assert fit.depth_m == pytest.approx(0.20, abs=0.005)
    assert fit.radius_m == pytest.approx(0.03, rel=0.3)
    # A point-diffractor model (R = 0) would put the centre at the top, 3 cm too shallow.
    assert fit.depth_m - fit.radius_m == pytest.approx(0.17, abs=0.003)


def test_interpret_finds_pipes_and_fills_their_cross_sections() -> None:
    pipes = [SyntheticTarget(0.45, 0.15, 0.03, amplitude=-1.0), SyntheticTarget(1.15, 0.28, 0.05, amplitude=-1.0)]
    section = interpret_bscan(_line(pipes), GPR, CFG, V)
    assert not section.velocity_estimated
    assert section.mask.shape == (len(section.z_m), len(section.x_m)) == section.image.shape
    assert len(section.detections) == 2
    for pipe, found in zip(pipes, section.detections, strict=True):
        assert found.x_m == pytest.approx(pipe.x_m, abs=0.01)
        assert found.depth_m == pytest.approx(pipe.depth_m, abs=0.01)
        assert found.radius_m == pytest.approx(pipe.radius_m, rel=0.3)
        assert 0.0 < found.score <= 1.0
        ix, iz = np.argmin(np.abs(section.x_m - pipe.x_m)), np.argmin(np.abs(section.z_m - pipe.depth_m))
        assert section.mask[iz, ix]  # filled at the centre, not only the bright top arc
        dx, dz = section.x_m[1] - section.x_m[0], section.z_m[1] - section.z_m[0]
        disk = section.mask[:, np.abs(section.x_m - pipe.x_m) <= 2 * pipe.radius_m].sum() * dx * dz
        assert disk == pytest.approx(math.pi * pipe.radius_m**2, rel=0.6)
    assert not section.mask[section.z_m > 0.4].any()


def test_air_filled_pipe_radius_from_its_inner_echo() -> None:
    pvc = SyntheticTarget(0.8, 0.22, 0.05, amplitude=0.43, inner_echo=-0.8)  # same sign as the direct wave
    section = interpret_bscan(_line([pvc]), GPR, CFG, V)
    (found,) = section.detections
    assert found.radius_m == pytest.approx(0.05, rel=0.1)
    assert found.depth_m == pytest.approx(0.22, abs=0.01)


@pytest.mark.parametrize("gap_m", [0.20, 0.23])
def test_overlapping_air_filled_pipes_are_both_found_on_their_tops(gap_m: float) -> None:
    """A tee's main and branch at one depth: hyperbolas cross, and each inner echo outshines its top."""
    main = SyntheticTarget(0.7, 0.22, 0.045, amplitude=0.35, inner_echo=-0.8)
    branch = SyntheticTarget(0.7 + gap_m, 0.22, 0.03, amplitude=0.35, inner_echo=-0.8)
    section = interpret_bscan(_line([main, branch]), GPR, CFG, V)
    assert len(section.detections) == 2
    for pipe, found in zip([main, branch], section.detections, strict=True):
        assert found.x_m == pytest.approx(pipe.x_m, abs=0.01)
        assert found.depth_m == pytest.approx(pipe.depth_m, abs=0.01)  # the inner echo would be ~2.5 cm deeper
        assert found.radius_m == pytest.approx(pipe.radius_m, rel=0.3)


def test_sideways_wander_over_an_oblique_pipe_is_undone() -> None:
    """The antenna wanders 4 mm off the line over a steel pipe at 60°: the crossing moves by y·cot 60°."""
    eps_r, angle = 7.0, math.radians(60.0)
    u = np.array([math.cos(angle), math.sin(angle), 0.0])
    centre = np.array([0.8, 0.0, -0.15])
    pipe = Pipe("steel", np.array([centre - 0.6 * u, centre + 0.6 * u]), 0.03, "metal")
    scene = Scene("wander", "", Slab((2.0, 1.2), (-0.2, -0.6), 0.42, eps_r, 18.0), (pipe,), None, None)
    x = np.arange(0.0, 1.6, 0.005)
    y = 0.004 * np.sin(2.0 * math.pi * x / 0.4 + 0.7)
    data = simulate_bscan(scene, np.column_stack([x, y]), GPR, np.random.default_rng(3))
    line = prepare_line(BScan(data, GPR.dt_ns, GPR.pre_trigger_ns, np.column_stack([x, y, 0 * x]), x / 0.1), GPR)
    assert np.max(np.abs(line.lateral_m - (y - y.mean())[::2][: len(line.x_m)])) < 0.001
    v = velocity_from_eps(eps_r)
    (h,) = hyperbolas_of_line(line, v, GPR, CFG)
    lateral = np.interp(h.x_m, line.x_m, line.lateral_m)
    prior = (math.sin(angle), 0.01)
    corrected = fit_cylinder(h.x_m, h.t_ns, v, GPR, sin_prior=prior, lateral_m=lateral, cot_sign=1.0)
    ignored = fit_cylinder(h.x_m, h.t_ns, v, GPR, sin_prior=prior)
    assert corrected.radius_m == pytest.approx(0.03, rel=0.1)
    assert corrected.depth_m == pytest.approx(0.15, abs=0.003)
    assert abs(ignored.radius_m / 0.03 - 1.0) > 2.5 * abs(corrected.radius_m / 0.03 - 1.0)


def test_velocity_estimated_when_unknown() -> None:
    v_true = velocity_from_eps(7.5)
    pipes = [SyntheticTarget(0.4, 0.12, 0.015, -1.0), SyntheticTarget(1.1, 0.25, 0.02, -1.0)]
    section = interpret_bscan(_line(pipes, v_true), GPR, CFG)
    assert section.velocity_estimated
    assert section.velocity_m_per_ns == pytest.approx(v_true, rel=0.03)
    assert len(section.detections) == 2


def test_too_short_bscan_is_refused_with_advice() -> None:
    b = _line([])
    short = BScan(b.data[:3], b.dt_ns, b.t0_ns, b.positions[:3], b.times[:3])
    with pytest.raises(InterpretationError, match="at least"):
        interpret_bscan(short, GPR, CFG, V)


def test_pngs_show_axes_mask_and_detections(tmp_path: Path) -> None:
    b = _line([SyntheticTarget(0.8, 0.2, 0.04, amplitude=-1.0)])
    section = interpret_bscan(b, GPR, CFG, V)
    write_bscan_png(tmp_path / "bscan.png", b)
    write_cross_section_png(tmp_path / "section.png", section, truth_mask=section.mask)
    picture = cv2.imread(str(tmp_path / "section.png"))
    assert picture is not None and picture.shape[0] > 200 and picture.shape[1] > 400
    green = (picture[..., 1] > 150) & (picture[..., 0] < 60) & (picture[..., 2] < 60)
    yellow = (picture[..., 1] > 180) & (picture[..., 2] > 200) & (picture[..., 0] < 60)
    assert green.any() and yellow.any()
    assert cv2.imread(str(tmp_path / "bscan.png")) is not None


def test_real_sir3000_file_is_interpretable(real_dzt: Path, tmp_path: Path) -> None:
    from gprbot.gpr.dzt import read_dzt

    dzt = read_dzt(real_dzt)
    b = bscan_from_dzt(dzt)
    assert math.isnan(b.t0_ns)  # the header's position is 0: time zero comes from the direct wave
    gpr = GprConfig(centre_frequency_mhz=400.0, samples=512, time_window_ns=dzt.header.range_ns,
                    pre_trigger_ns=math.nan, antenna_height_m=0.0, tx_rx_offset_m=0.16)
    part = BScan(b.data[:300], b.dt_ns, b.t0_ns, b.positions[:300], b.times[:300])
    section = interpret_bscan(part, gpr, InterpretationConfig(depth_max_m=2.0), velocity_from_eps(dzt.header.eps_r))
    assert section.image.shape == section.mask.shape
    assert section.x_m[-1] == pytest.approx(299 / dzt.header.traces_per_m, abs=0.03)
    write_cross_section_png(tmp_path / "real.png", section)
    assert (tmp_path / "real.png").stat().st_size > 0
