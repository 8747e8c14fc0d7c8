"""The simulator-vs-FDTD calibration: scene conversion, time axis, correlation and the report writer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gprbot.sim.variation import SignalVariation
from validation import calib_measure as m
from validation.calib_scene import FDTD_DATA, load_fdtd, loss_db_per_m, render_ours, to_gpr_config, to_sim_scene
from validation.calibration import ReflectorRow, SceneResult, compare, kept_findings, report, residual_table

SCENE = "metal_pipe_2600"  # the smallest committed scene: one metal pipe


def _truth() -> dict:
    return {"name": "t", "frequency_mhz": 1000.0, "eps_r": 6.25, "conductivity_s_per_m": 0.01,
            "velocity_m_per_ns": 0.299792458 / 2.5, "antenna": {"height_m": 0.02, "tx_rx_offset_m": 0.04},
            "dt_ns": 0.025, "source_peak_ns": math.sqrt(2.0), "trace_x_m": [i * 0.01 for i in range(41)],
            "pipes": [{"x_m": 0.2, "depth_m": 0.15, "radius_m": 0.02, "fill": "metal", "wall_m": 0.0}],
            "rebars": [{"x_m": 0.1, "depth_m": 0.05, "radius_m": 0.006}], "slab_bottom_m": None}


def test_scene_conversion_puts_the_pipe_across_the_line_at_its_x_and_depth() -> None:
    scene = to_sim_scene(_truth())
    pipe, bar = scene.pipes
    assert pipe.fill == "metal" and pipe.radius_m == 0.02
    assert np.allclose(pipe.points[:, 0], 0.2) and np.allclose(pipe.points[:, 2], -0.15)
    assert pipe.points[0, 1] < 0.0 < pipe.points[1, 1]  # along y, crossing the line y = 0
    assert np.allclose(bar.points[:, 0], 0.1) and bar.radius_m == 0.006
    assert scene.slab.thickness_m > 10.0 and scene.slab.eps_r == 6.25


def test_time_axis_puts_the_transmit_instant_at_the_source_peak() -> None:
    truth = _truth()
    gpr = to_gpr_config(truth, 400)
    assert gpr.pre_trigger_ns == pytest.approx(truth["source_peak_ns"]) and gpr.dt_ns == pytest.approx(0.025)
    ours = render_ours(truth, 400)
    i = 20  # the trace over the pipe
    env = m.envelope(ours - ours.mean(0))[i]
    r = m.reflectors(truth)[0]
    t0 = m.predicted_ns(truth, 0.2, r)
    t, _ = m.pick(env, t0, 0.5, truth["dt_ns"])
    assert t == pytest.approx(t0, abs=0.05)


def test_loss_of_a_low_loss_concrete_matches_the_textbook_formula() -> None:
    db = loss_db_per_m(_truth())
    assert db == pytest.approx(8.686 * 0.01 * 376.73 / (2 * 2.5), rel=0.01)


def test_correlation_of_a_bscan_with_itself_is_one_and_a_shift_is_found() -> None:
    rng = np.random.default_rng(1)
    b = m.preprocess(rng.normal(size=(5, 200)))
    assert m.ncc(b, b) == pytest.approx(1.0)
    assert m.ncc(b, -b) == pytest.approx(-1.0)
    lag, c = m.best_shift(m.shift_samples(b, 3), b, 6)
    assert lag == 3 and c > 0.98


def test_a_committed_scene_compares_with_finite_figures() -> None:
    if not (FDTD_DATA / f"{SCENE}.DZT").exists():
        pytest.skip("FDTD scene not committed")
    data, truth = load_fdtd(SCENE)
    assert data.shape[0] == len(truth["trace_x_m"])
    s = compare(SCENE)
    assert s.polarity in (-1.0, 1.0) and -1.0 <= s.ncc <= 1.0 and s.ncc_shifted >= s.ncc
    (row,) = s.rows
    assert abs(row.dt_apex) < 0.5 * 1e3 / truth["frequency_mhz"]
    assert math.isfinite(row.amp_vs_direct)


def test_report_writer_makes_tables_and_keeps_the_findings(tmp_path) -> None:
    row = ReflectorRow("s", "pipe metal", 0.02, 0.15, 3.0, 3.1, 1.5, math.nan, math.nan, {30.0: 0.01}, {30.0: 0.6})
    s = SceneResult("s", "dev", 1600.0, "", 0.6, 0.9, 0.07, 0.8, -1.0, -0.93, 0.07, (1800.0, 1600.0),
                    (1850.0, 1650.0), 0.9, [row])
    text = report([s], "our findings", "abc123")
    assert "`abc123`" in text and "| s | dev | 1600 | -1 | 0.60 |" in text and "| pipe metal | 1 |" in text
    path = tmp_path / "r.md"
    path.write_text(text)
    assert kept_findings(path) == "our findings"


def test_residual_row_and_the_surface_multiple_of_a_metal_pipe() -> None:
    if not (FDTD_DATA / f"{SCENE}.DZT").exists():
        pytest.skip("FDTD scene not committed")
    s = compare(SCENE)
    (row,) = s.rows
    ours, fdtd = row.multiple
    assert 0.0 < ours < 1.0 and 0.0 < fdtd < 1.0  # a multiple is weaker than its primary
    head, _, line = residual_table([s])
    assert "multiple/primary O" in head and f"{ours:.3f}" in line


def test_a_variation_changes_ours_and_keeps_the_kinematics() -> None:
    if not (FDTD_DATA / f"{SCENE}.DZT").exists():
        pytest.skip("FDTD scene not committed")
    plain, rotated = compare(SCENE), compare(SCENE, SignalVariation(phase_deg=90.0))
    assert rotated.ncc != pytest.approx(plain.ncc, abs=1e-3)
    assert rotated.rows[0].dt_apex == pytest.approx(plain.rows[0].dt_apex, abs=0.05)  # envelopes barely move
