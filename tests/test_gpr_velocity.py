"""Velocity from hyperbolas: with antenna height and Tx–Rx offset it is right, without them it is not."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import optimize

from gprbot.config import GprConfig, InterpretationConfig
from gprbot.errors import InterpretationError
from gprbot.gpr import velocity
from gprbot.gpr.bscan import BScan, SyntheticTarget, synthetic_bscan
from gprbot.gpr.cylinder import fit_cylinder
from gprbot.gpr.hyperbola import HyperbolaPicks, hyperbolas_of_line
from gprbot.gpr.line_model import cylinder_times, prepare_line
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.gpr.velocity import (
    V_GUESS_M_PER_NS,
    chain_radii,
    estimate_velocity,
    fit_shared_velocity,
    link_crossing_angles,
    link_crossings,
    pipe_chains,
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


@pytest.mark.parametrize("angle_deg", [55.0, 125.0])
def test_crossing_angle_sign_says_which_way_the_pipe_leans(angle_deg: float) -> None:
    angle = math.radians(angle_deg)
    apices = [[(np.array([0.5 + y / math.tan(angle), y]), 2.0, -1.0)] for y in (0.0, 0.1, 0.2)]
    for direction in (np.array([1.0, 0.0]), np.array([-1.0, 0.0])):  # boustrophedon: either sense
        (middle,) = link_crossing_angles(apices, [direction] * 3)[1]
        assert middle is not None
        assert middle[0] == pytest.approx(math.sin(angle), abs=1e-9)
        assert middle[1] == math.copysign(1.0, 1.0 / math.tan(angle))


def test_chains_link_one_pipe_across_lines_and_share_its_radius() -> None:
    # Two pipes: one at 55°, seen on four lines; one perpendicular and deeper (another apex time).
    angle = math.radians(55.0)
    lines_y = (0.0, 0.1, 0.2, 0.3)
    apices = [[(np.array([0.5 + y / math.tan(angle), y]), 2.0, -1.0), (np.array([1.4, y]), 3.5, -1.0)]
              for y in lines_y]
    chains = pipe_chains(apices)
    assert len({c[0] for c in chains}) == 1 and len({c[1] for c in chains}) == 1
    assert chains[0][0] != chains[0][1]
    flat = [c for line in chains for c in line]
    v = 0.1
    rng = np.random.default_rng(3)
    x = np.linspace(-0.25, 0.25, 41)

    def picks(x0: float, dc: float, radius: float, sin_cross: float) -> tuple[HyperbolaPicks, float]:
        t = cylinder_times(x + x0, x0, dc, radius, v, GPR, sin_cross) + rng.normal(0.0, 0.005, x.size)
        return HyperbolaPicks(x + x0, t, np.ones_like(x), -1.0, x0, float(t.min()), 1.0, (x0, dc, v)), sin_cross

    members = [picks(0.5, 0.20, 0.030, math.sin(angle)) if k == 0 else picks(1.4, 0.35, 0.015, 1.0)
               for _ in lines_y for k in (0, 1)]
    alone = [fit_cylinder(h.x_m, h.t_ns, v, GPR, sin_prior=(s, 0.02)).radius_m for h, s in members]
    shared = chain_radii(flat, members, v, GPR)
    # one line alone scatters by a third of the radius (0.028-0.037 and 0.010-0.014 here); together:
    assert np.ptp(alone[0::2]) > 0.008 and np.ptp(alone[1::2]) > 0.003
    assert shared[chains[0][0]] == pytest.approx(0.030, rel=0.15)
    assert shared[chains[0][1]] == pytest.approx(0.015, rel=0.15)
    assert chain_radii(flat[:4], members[:4], v, GPR) == {}  # two lines per pipe are too few to vote


def test_no_hyperbola_means_no_velocity() -> None:
    with pytest.raises(InterpretationError, match="eps_r"):
        estimate_velocity([_line(6.5, targets=[])], GPR, CFG)


def _lagging_picks(lag_ns: float) -> tuple[HyperbolaPicks, GprConfig, float]:
    """A 1.5 cm pipe's picks (metal_pipe_2600's geometry) whose flanks lag the ray model beyond 35°, as
    gprMax's do: lag_ns per 10° past 35°."""
    gpr, v, x0, centre, radius = GprConfig(antenna_height_m=0.01, tx_rx_offset_m=0.03), 0.1224, 0.22, 0.10, 0.015
    x = np.arange(-0.08, 0.0801, 0.005) + x0
    angle = np.degrees(np.arctan(np.abs(x - x0) / (centre - radius)))
    t = cylinder_times(x, x0, centre, radius, v, gpr) + lag_ns * np.clip((angle - 35.0) / 10.0, 0.0, None)
    apex = int(np.argmin(t))
    return HyperbolaPicks(x, t, np.ones_like(x), 1.0, float(x[apex]), float(t[apex]), 1.0, (x0, centre, v)), gpr, v


def test_held_fit_does_not_slide_along_the_radius_valley_when_wide_flanks_lag() -> None:
    picks, gpr, v_true = _lagging_picks(0.03)
    v, _, params, _ = fit_shared_velocity([picks], gpr, V_GUESS_M_PER_NS, held=True)
    assert v == pytest.approx(v_true, rel=0.05)
    assert params[0, 2] < 0.03
    # the same picks read to 60° with a free radius: R runs to several cm and v far too slow
    v_free, _, params_free, _ = fit_shared_velocity([picks], gpr, V_GUESS_M_PER_NS)
    assert v_free < 0.8 * v_true
    assert params_free[0, 2] > 0.05


def test_free_fit_is_exact_where_the_flanks_follow_the_ray_model() -> None:
    picks, gpr, v_true = _lagging_picks(0.0)
    v, _, params, _ = fit_shared_velocity([picks], gpr, V_GUESS_M_PER_NS)
    assert v == pytest.approx(v_true, rel=0.002)
    assert params[0, 2] == pytest.approx(0.015, abs=0.002)
    held, _, _, _ = fit_shared_velocity([picks], gpr, V_GUESS_M_PER_NS, held=True)
    assert abs(held / v_true - 1.0) <= velocity.FLANKS_AGREE  # so estimate_velocity keeps the free one
