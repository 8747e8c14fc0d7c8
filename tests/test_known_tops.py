"""A survey's velocity calibrated on known covers (gpr.known_tops, `gprbot replay --known-top`)."""

from __future__ import annotations

import argparse
import math
from dataclasses import replace

import numpy as np
import pytest

from gprbot.cli import _site_top
from gprbot.config import Config, GprConfig, load_config
from gprbot.config_ranges import check_ranges
from gprbot.errors import ConfigError
from gprbot.gpr.bscan import BScan, SyntheticTarget, synthetic_bscan
from gprbot.gpr.preprocess import preprocess
from gprbot.infer.known_tops import calibrate_survey, on_nearest_line
from gprbot.infer.pipeline import survey_velocity

V = 0.1
GPR = replace(GprConfig(), centre_frequency_mhz=900.0, antenna_height_m=0.02, tx_rx_offset_m=0.06, eps_r=None)


def _line(y: float, targets: list[SyntheticTarget], seed: int) -> BScan:
    """A 2 m line along x at site y, time zero unknown (as recorded)."""
    b = synthetic_bscan(targets, v_m_per_ns=V, centre_frequency_mhz=900.0, n_traces=200, spacing_m=0.01,
                        samples=512, dt_ns=0.025, t0_ns=1.0, antenna_height_m=GPR.antenna_height_m,
                        tx_rx_offset_m=GPR.tx_rx_offset_m, noise=0.01, direct_wave=3.0,
                        rng=np.random.default_rng(seed))
    positions = np.asarray(b.positions, dtype=np.float64).copy()
    positions[:, 0] += 0.5  # the survey starts at site x = 0.5 m
    positions[:, 1] = y
    return replace(b, positions=positions, t0_ns=math.nan)


def _survey() -> dict[int, BScan]:
    """Two lines 0.2 m apart over a pipe crossing them at site x 1.3 m (top 0.20 m down), a bar 1.5 cm to its left
    at 0.06 m cover (an earlier apex within the search window), and a pipe at x 1.9 m."""
    targets = [SyntheticTarget(0.8, 0.225, 0.025, 1.0), SyntheticTarget(0.785, 0.066, 0.006, 0.5),
               SyntheticTarget(1.4, 0.32, 0.02, 1.0)]
    return {k: preprocess(_line(0.2 * k, targets, k), GPR) for k in range(2)}


def test_a_known_top_on_a_line_calibrates_the_surveys_velocity() -> None:
    lines = _survey()
    line, along, off = on_nearest_line(lines, (1.3, 0.21))  # type: ignore[misc]
    assert line == 1 and abs(along - 0.8) < 0.02 and abs(off - 0.01) < 1e-6
    cal = calibrate_survey(lines, GPR, [(1.3, 0.2, 0.20)], prior_v=0.12)
    assert cal.v is not None and abs(cal.v / V - 1.0) < 0.05 and "line 1" in cal.method and not cal.notes
    # Without a rough velocity the earliest apex near the position is taken: the bar's, 1.5 cm aside.
    earliest = calibrate_survey(lines, GPR, [(1.3, 0.2, 0.20)])
    assert earliest.v is None or abs(earliest.v / V - 1.0) > 0.2
    far = calibrate_survey(lines, GPR, [(1.3, 0.7, 0.20)], prior_v=0.12)  # 0.5 m beside the last line
    assert far.v is None and "50 cm from the nearest line" in far.notes[0]


def test_survey_velocity_says_it_was_calibrated() -> None:
    cfg = replace(load_config(), gpr=replace(GPR, known_tops=((1.3, 0.0, 0.20),)))
    found = survey_velocity(_survey(), cfg)
    v, estimated, method = found.v, found.estimated, found.method
    assert abs(v / V - 1.0) < 0.05 and not estimated and method.startswith("calibrated on 1 known top")


def test_known_tops_and_eps_r_are_one_or_the_other_and_depths_are_positive() -> None:
    base = Config()
    with pytest.raises(ConfigError, match=r"gpr\.known_tops: the velocity is fixed by gpr\.eps_r"):
        check_ranges(replace(base, gpr=replace(base.gpr, eps_r=6.0, known_tops=((0.0, 0.0, 0.1),))))
    with pytest.raises(ConfigError, match=r"gpr.known_tops\[0\]: the third number is the depth"):
        check_ranges(replace(base, gpr=replace(base.gpr, eps_r=None, known_tops=((0.0, 0.0, -0.1),))))


def test_the_replay_option_reads_x_y_and_depth() -> None:
    assert _site_top("0.85,0.40:0.06") == (0.85, 0.40, 0.06)
    for bad in ("0.85:0.06", "0.85,0.4:0", "a,b:c", "0.85,nan:0.1"):
        with pytest.raises(argparse.ArgumentTypeError):
            _site_top(bad)


def test_survey_velocity_says_how_many_hyperbolas_gave_it_and_warns_where_they_hardly_constrain_it(
    caplog: pytest.LogCaptureFixture,
) -> None:
    from gprbot.gpr.velocity import VelocityEstimate
    from gprbot.infer.pipeline import estimate_words

    found = survey_velocity(_survey(), replace(load_config(), gpr=GPR))
    v, estimated, method = found.v, found.estimated, found.method
    assert estimated and abs(v / V - 1.0) < 0.05
    assert method.startswith("estimated from ") and " hyperbolas on the lines, ±" in method and "hardly" not in method
    assert found.sigma > 0 and f"±{found.sigma:.4f} m/ns" in method  # the stated sigma, as a number and in words
    with caplog.at_level("WARNING"):
        lone = estimate_words(VelocityEstimate(0.154, 0.216, 1))  # a simulated survey's lone 1.4 cm pipe
    assert lone.startswith("estimated from 1 hyperbola on the lines, ±0.2160 m/ns")
    assert "hardly constrain" in lone and "gpr.eps_r" in lone and "hardly constrain" in caplog.text
