"""The chain's radii from a segmentation of the section (chain.sizing), alone, in `interpret`, and through the CLI."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import pytest

from gprbot.apps.interpret_file import interpret_file
from gprbot.config import GprConfig, load_config
from gprbot.gpr.bscan import BScan, Detection, SyntheticTarget, synthetic_bscan
from gprbot.gpr.chain.classify import ClassifiedDetection
from gprbot.gpr.chain.fit import CylinderFit
from gprbot.gpr.chain.run import interpret
from gprbot.gpr.chain.sizing import sized

V = 0.1
GPR = replace(GprConfig(), centre_frequency_mhz=900.0, antenna_height_m=0.02, tx_rx_offset_m=0.06)


def _detection(top: float, radius: float, source: str, kind: str = "pipe") -> ClassifiedDetection:
    fit = CylinderFit(0.5, top, radius, V, 0.001, 0.001, radius, 0.0, 0.01, 30)
    return ClassifiedDetection(0.5, top + radius, radius, radius, source == "fit", kind, "slower",  # type: ignore[arg-type]
                               0.8, fit, None, radius_source=source)  # type: ignore[arg-type]


def test_an_unmeasured_radius_takes_the_blob_at_its_top() -> None:
    d = _detection(0.10, 0.004, "none")
    (out,) = sized([d], [Detection(0.51, 0.10 + 0.03, 0.03, 0.9)])
    assert out.radius_m == 0.03 and out.depth_m == pytest.approx(0.13) and out.radius_source == "migrationnet"
    assert out.fit.top_m == 0.10 and out.x_m == d.x_m and 0 < out.radius_sigma_m < 0.03  # the top stays the curve's


def test_a_measured_radius_a_rebar_and_blobs_elsewhere_are_left_alone() -> None:
    blob = Detection(0.5, 0.13, 0.03, 0.9)
    measured, bar = _detection(0.10, 0.02, "fit"), _detection(0.10, 0.004, "none", "rebar")
    open_ = _detection(0.10, 0.004, "none")
    assert sized([measured, bar], [blob]) == (measured, bar)
    below = Detection(0.5, 0.20, 0.03, 0.9)  # a blob under the pipe (its echo, or another pipe): top 7 cm deeper
    aside = Detection(0.6, 0.13, 0.03, 0.9)  # 10 cm along the line
    assert sized([open_], [below, aside]) == (open_,)


def _line(targets: list[SyntheticTarget]) -> BScan:
    """A 2.3 m line at 900 MHz, time zero unknown (as a file gives it)."""
    b = synthetic_bscan(targets, v_m_per_ns=V, centre_frequency_mhz=900.0, n_traces=230, spacing_m=0.01,
                        samples=512, dt_ns=0.025, t0_ns=1.0, antenna_height_m=GPR.antenna_height_m,
                        tx_rx_offset_m=GPR.tx_rx_offset_m, noise=0.1, direct_wave=3.0)
    return replace(b, t0_ns=math.nan)


def test_interpret_asks_the_sizer_only_when_a_pipe_needs_it() -> None:
    calls: list[float] = []

    def sizer(v: float) -> tuple[Detection, ...]:
        calls.append(v)
        return (Detection(0.8, 0.246, 0.05, 0.9),)  # a 5 cm blob whose top lies at the bar's, 19.6 cm down

    b = _line([SyntheticTarget(0.8, 0.2, 0.004, 1.0)])  # a thin bar in noise: the curve does not measure it
    own = interpret(b, GPR, V)
    assert own.pipes and all(d.radius_source == "none" for d in own.pipes)
    sized_ = interpret(b, GPR, V, sizer=sizer)
    assert calls == [V]
    (pipe,) = [d for d in sized_.pipes if abs(d.x_m - 0.8) < 0.02]
    assert pipe.radius_source == "migrationnet" and pipe.radius_m == 0.05
    assert pipe.depth_m == pytest.approx(pipe.fit.top_m + 0.05)
    assert any(d.radius_supported for d in sized_.section.detections)  # the picture no longer marks it "(?)"
    calls.clear()
    interpret(_line([]), GPR, V, sizer=sizer)  # no pipe: no segmentation run
    assert calls == []


FDTD = Path(__file__).resolve().parents[1] / "validation" / "fdtd" / "data"


def test_the_cli_sizes_an_fdtd_pipe_with_migrationnet_and_says_so(tmp_path: Path) -> None:
    truth = json.loads((FDTD / "metal_pipe_2600.json").read_text())
    (true_pipe,) = truth["pipes"]
    ant = truth["antenna"]
    cfg = load_config()
    runs = {}
    for radius_from in ("migrationnet", "fit"):
        config = replace(cfg, interpretation=replace(cfg.interpretation, radius_from=radius_from))
        out = tmp_path / radius_from
        interpret_file(FDTD / "metal_pipe_2600.DZT", out, truth["velocity_m_per_ns"], height_m=ant["height_m"],
                       offset_m=ant["tx_rx_offset_m"], config=config)
        (runs[radius_from],) = json.loads((out / "detections.json").read_text())["detections"]
    net, fit = runs["migrationnet"], runs["fit"]
    assert net["radius_from"] == "MigrationNet pipe mask" and fit["radius_from"].startswith("not measured")
    assert abs(net["radius_m"] / true_pipe["radius_m"] - 1.0) <= 0.3  # 1.64 cm for 1.5 cm; the fit's: 0.27 cm
    assert net["cover_m"] == fit["cover_m"] and abs(net["depth_m"] - true_pipe["depth_m"]) <= 0.01


def test_a_survey_line_without_the_model_still_gives_its_pipes(caplog: pytest.LogCaptureFixture) -> None:
    from gprbot.gpr.preprocess import preprocess
    from gprbot.infer.pipeline import line_section

    cfg = load_config()
    cfg = replace(cfg, gpr=GPR, interpretation=replace(cfg.interpretation, method="chain", radius_from="migrationnet",
                                                       migrationnet_model="models/no_such_model.onnx"))
    b = preprocess(_line([SyntheticTarget(0.8, 0.2, 0.004, 1.0)]), GPR)
    with caplog.at_level("WARNING"):
        section = line_section(b, cfg, V)
    assert section.detections and "no_such_model.onnx" in caplog.text and "radii from the hyperbolas" in caplog.text
