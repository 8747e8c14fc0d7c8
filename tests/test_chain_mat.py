"""The chain's rebar-mat stage: a periodic response found, taken out, and what it hid searched for."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from gprbot.config import GprConfig
from gprbot.gpr.bscan import BScan, SyntheticTarget, synthetic_bscan
from gprbot.gpr.chain import run
from gprbot.gpr.chain.mat import find_mat, periodic_response, without_mat
from gprbot.gpr.chain.prepare import prepare
from validation.cases import FDTD_DATA, fdtd_cases

V = 0.1
GPR = replace(GprConfig(), centre_frequency_mhz=900.0, antenna_height_m=0.02, tx_rx_offset_m=0.06)
SPACING = 0.12
PIPE = SyntheticTarget(1.13, 0.30, 0.03, 0.3)


def _line(targets: list[SyntheticTarget]) -> BScan:
    b = synthetic_bscan(targets, v_m_per_ns=V, centre_frequency_mhz=900.0, n_traces=230, spacing_m=0.01, samples=512,
                        dt_ns=0.025, t0_ns=1.0, antenna_height_m=GPR.antenna_height_m,
                        tx_rx_offset_m=GPR.tx_rx_offset_m, noise=0.01, direct_wave=3.0)
    return replace(b, t0_ns=math.nan)


def _mat() -> list[SyntheticTarget]:
    return [SyntheticTarget(0.05 + k * SPACING, 0.045, 0.006, 1.0) for k in range(19)]


def test_a_mat_is_found_with_its_spacing() -> None:
    mat = find_mat(prepare(_line([*_mat(), PIPE]), GPR))
    assert mat is not None
    assert mat.spacing_m == pytest.approx(SPACING, rel=0.01)


def test_targets_at_no_regular_spacing_make_no_mat() -> None:
    targets = [SyntheticTarget(x, d, 0.01, 1.0) for x, d in ((0.4, 0.12), (0.75, 0.2), (1.45, 0.15), (1.9, 0.25))]
    assert find_mat(prepare(_line(targets), GPR)) is None


def test_taking_the_mat_out_leaves_the_pipe_standing_out() -> None:
    prep = prepare(_line([*_mat(), PIPE]), GPR)
    mat = find_mat(prep)
    assert mat is not None
    below = without_mat(prep, mat)
    # Away from the line's ends (where the response is estimated from one side) the mat is gone...
    inner = ((prep.x_m > 0.3) & (prep.x_m < 0.5)) | ((prep.x_m > 1.8) & (prep.x_m < 2.0))
    assert np.sum(below.data[inner] ** 2) < 0.1 * np.sum(prep.data[inner] ** 2)
    # ... and the pipe's top stands out of its row, as it does not with the mat in.
    col = int(np.argmin(np.abs(prep.x_m - PIPE.x_m)))
    apex = int((prep.t0_ns + 2.0 * (PIPE.depth_m - PIPE.radius_m) / V) / prep.dt_ns)
    rows = slice(apex - 10, apex + 30)

    def standing(env: np.ndarray) -> float:
        k = apex - 10 + int(np.argmax(env[col, rows]))
        return float(env[col, k] / np.median(env[:, k]))

    assert standing(below.envelope) > 2.0 * standing(prep.envelope)  # measured: 6.1 -> 16.8


def test_the_response_at_a_trace_leaves_that_trace_out() -> None:
    data = np.zeros((50, 4))
    data[20] = 1.0  # one trace unlike the others: a pipe's apex, not the period's
    assert np.all(periodic_response(data, 0.01, 0.1)[20] == 0.0)


def test_pipes_under_a_dense_fdtd_mat_are_found(monkeypatch: pytest.MonkeyPatch) -> None:
    case = next(c for c in fdtd_cases() if c.name == "mesh_pipe_1200")  # dev half: bars every 12 cm, 3.5 cm down
    assert case.group == "fdtd-dev"
    bscan, gpr = case.load()
    pipes = [t for t in case.targets if t.kind == "pipe"]

    def found(result: run.Interpretation) -> int:
        return sum(any(abs(d.x_m - t.x_m) <= 0.03 and abs(d.depth_m - t.depth_m) <= 0.03 for d in result.pipes)
                   for t in pipes)

    assert (FDTD_DATA / "mesh_pipe_1200.json").exists()
    assert found(run.interpret(bscan, gpr, case.velocity)) == 2
    monkeypatch.setattr(run, "find_mat", lambda prep: None)  # the chain without its mat stage
    assert found(run.interpret(bscan, gpr, case.velocity)) == 1
