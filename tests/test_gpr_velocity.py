"""Velocity from hyperbolas: with antenna height and Tx–Rx offset it is right, without them it is not."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import optimize

from gprbot.config import GprConfig, InterpretationConfig
from gprbot.errors import InterpretationError
from gprbot.gpr.bscan import BScan, SyntheticTarget, synthetic_bscan
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.gpr.velocity import (
    V_GUESS_M_PER_NS,
    HyperbolaPicks,
    estimate_velocity,
    hyperbolas_of_line,
    link_crossings,
    prepare_line,
)

CFG = InterpretationConfig()
GPR = GprConfig(antenna_height_m=0.04, tx_rx_offset_m=0.10)
PIPES = [SyntheticTarget(0.30, 0.10, 0.010), SyntheticTarget(0.75, 0.16, 0.020),
         SyntheticTarget(1.20, 0.24, 0.015), SyntheticTarget(1.60, 0.32, 0.030)]


def _line(eps_r: float, targets: list[SyntheticTarget] = PIPES) -> BScan:
    return synthetic_bscan(
        targets, v_m_per_ns=velocity_from_eps(eps_r), centre_frequency_mhz=900.0, n_traces=190,
        spacing_m=0.01, samples=512, dt_ns=GPR.dt_ns, t0_ns=1.0, antenna_height_m=GPR.antenna_height_m,
        tx_rx_offset_m=GPR.tx_rx_offset_m, noise=0.01, direct_wave=2.0, footprint_power=2.0,
        rng=np.random.default_rng(7),
    )


def _naive_velocity(h: HyperbolaPicks) -> float:
    """The textbook fit t² = t0² + 4(x − x0)²/v² within 35°, ignoring height, offset and radius."""
    depth = h.point_model[1]
    near = np.abs(h.x_m - h.apex_x_m) <= depth * math.tan(math.radians(35.0))
    x, t = h.x_m[near], h.t_ns[near]
    sol = optimize.least_squares(lambda p: np.sqrt(p[1] ** 2 + 4 * (x - p[0]) ** 2 / p[2] ** 2) - t,
                                 [h.apex_x_m, h.apex_t_ns, V_GUESS_M_PER_NS])
    return float(sol.x[2])


@pytest.mark.parametrize("eps_r", [5.0, 6.5, 8.0])
def test_velocity_recovered_with_height_and_offset(eps_r: float) -> None:
    v_true = velocity_from_eps(eps_r)
    estimate = estimate_velocity([_line(eps_r)], GPR, CFG)
    assert estimate.n_targets == 4
    assert estimate.v == pytest.approx(v_true, rel=0.02)
    assert 0.0 < estimate.std < 0.02 * v_true


def test_naive_fit_without_height_and_offset_is_measurably_worse() -> None:
    v_true = velocity_from_eps(6.5)
    ours = abs(estimate_velocity([_line(6.5)], GPR, CFG).v / v_true - 1.0)
    line = prepare_line(_line(6.5), GPR)
    naive = [abs(_naive_velocity(h) / v_true - 1.0) for h in hyperbolas_of_line(line, V_GUESS_M_PER_NS, GPR, CFG)]
    assert len(naive) == 4
    assert float(np.median(naive)) > 0.10  # DESIGN §5: 10–40 % off
    assert float(np.median(naive)) > 10.0 * ours


def test_crossing_angle_from_neighbouring_lines() -> None:
    angle = math.radians(55.0)  # the pipe runs at 55° to the lines (along x), lines 0.1 m apart in y
    direction = np.array([1.0, 0.0])
    apices = [[(np.array([0.5 + y / math.tan(angle), y]), 2.0, -1.0)] for y in (0.0, 0.1, 0.2)]
    apices[1].append((np.array([1.5, 0.1]), 3.0, 1.0))  # another pipe with no twins
    sines = link_crossings(apices, [direction] * 3)
    assert sines[1][0] == pytest.approx(math.sin(angle), abs=1e-9)
    assert sines[0][0] == pytest.approx(math.sin(angle), abs=1e-9)
    assert sines[1][1] is None


def test_no_hyperbola_means_no_velocity() -> None:
    with pytest.raises(InterpretationError, match="eps_r"):
        estimate_velocity([_line(6.5, targets=[])], GPR, CFG)
