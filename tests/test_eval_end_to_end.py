"""The end-to-end evaluation: every chain on a survey, refusals scored, FDTD B-scans laid on parallel lines."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

pytest.importorskip("torch")

from gprbot.config import load_config
from training import eval_end_to_end
from training.chamfer import cloud_metrics
from training.e2e_surveys import fdtd_survey, simulated_survey
from training.pointcloud_data import make_sample
from validation.cases import FDTD_DATA, fdtd_cases


def _survey(seed: int) -> eval_end_to_end.Survey:
    sample = make_sample(seed)
    assert sample is not None
    data = {"seed": np.array([sample.seed]), "case": np.array([sample.case]), "centre": sample.centre[None],
            "scale": np.array([sample.scale]), "dense": sample.dense[None]}
    return simulated_survey(0, data, load_config().gpr)


def test_one_scene_through_every_chain() -> None:
    rows = eval_end_to_end.evaluate_survey(_survey(200000), load_config())
    chains = {(r["interpretation"], r["completion"]) for r in rows}
    assert chains == {(m, c) for m in eval_end_to_end.INTERPRETERS for c in eval_end_to_end.COMPLETIONS}
    by_chain = {(r["interpretation"], r["completion"]): r for r in rows}
    classical = by_chain["classical", "geometric"]
    assert classical["refused"] is None and classical["found"] >= 1 and abs(classical["velocity_err_rel"]) < 0.1
    assert classical["cd2"] < 5e-3  # a found pipe's cylinder lies far closer to the truth than a blob
    # pipes.json comes from the fit through the slices whichever completion makes the dense cloud
    assert by_chain["classical", "gprnet"]["horizontal_m"] == classical["horizontal_m"]
    summary = eval_end_to_end.summarise(rows)
    assert 0.0 < summary["pipe_recall"] <= 1.0 and summary["refused"] == 0


def test_a_refused_scene_is_scored_as_finding_nothing() -> None:
    survey = _survey(200003)
    rng = np.random.default_rng(0)  # receiver noise alone: no reflection hyperbola to estimate the velocity from
    quiet = {line: dataclasses.replace(b, data=rng.normal(0.0, 0.5, b.data.shape).astype(np.float32))
             for line, b in survey.bscans.items()}
    survey = dataclasses.replace(survey, bscans=quiet)
    rows = eval_end_to_end.evaluate_survey(survey, load_config())
    assert len(rows) == len(eval_end_to_end.INTERPRETERS) * len(eval_end_to_end.COMPLETIONS)
    assert all("hyperbola" in r["refused"] for r in rows)
    assert all(r["true"] >= 1 and r["found"] == r["extra"] == r["partial"] == 0 for r in rows)
    assert survey.dense is not None
    nothing = cloud_metrics(eval_end_to_end.NOTHING, survey.dense)
    assert all(r["cd2"] == pytest.approx(nothing.cd2) for r in rows)
    summary = eval_end_to_end.summarise(rows)
    n = len(eval_end_to_end.INTERPRETERS) * len(eval_end_to_end.COMPLETIONS)
    assert summary["scenes"] == n and summary["refused"] == n and summary["pipe_recall"] == 0.0
    result = eval_end_to_end.evaluate([lambda: survey], "sim")
    text = eval_end_to_end.markdown(result, "cmd")
    assert "from simulated B-scans, velocity estimated: 1 surveys" in text
    assert "| classical + geometric | 1 | 1 |" in text and "seed 200003 (classical): no reflection" in text


def test_an_fdtd_scene_becomes_a_survey_of_identical_lines() -> None:
    case = next(c for c in fdtd_cases() if c.name == "two_pipes_1600")
    record = json.loads((FDTD_DATA / "two_pipes_1600.json").read_text())
    survey = fdtd_survey(case, record)
    bscan, _ = case.load()
    assert 5 <= len(survey.bscans) <= 12 and survey.case == "two_pipes"
    lines = sorted(survey.bscans)
    first, last = survey.bscans[lines[0]], survey.bscans[lines[-1]]
    # the same cross-section on every line, the receiver noise drawn afresh for each
    assert np.corrcoef(first.data.ravel(), last.data.ravel())[0, 1] > 0.99
    assert not np.array_equal(first.data, last.data) and not np.array_equal(first.data, bscan.data)
    spacing = np.median(last.positions[:, 1] - first.positions[:, 1]) / (lines[-1] - lines[0])
    assert 0.05 <= spacing <= 0.25
    assert np.abs(first.positions[:, 0] - bscan.positions[:, 0]).max() < 0.05  # pose noise of at most 1 cm σ
    # truth: the 2D pipes extruded along y across every line, at their x and centre depth
    assert [(p.points[0, 0], -p.points[0, 2]) for p in survey.truth.pipes] == [(0.195, 0.15), (0.295, 0.15)]
    ymin, ymax = survey.region[2:]
    assert all(p.points[0, 1] < ymin and p.points[-1, 1] > ymax for p in survey.truth.pipes)
    assert survey.dense is not None and np.ptp(survey.dense, axis=0).max() == pytest.approx(1.0, abs=1e-5)


def test_a_survey_the_hyperbola_fits_find_no_velocity_on_gets_the_chains() -> None:
    from gprbot.errors import InterpretationError
    from gprbot.gpr.preprocess import preprocess
    from gprbot.gpr.velocity import estimate_velocity
    from gprbot.infer.pipeline import survey_velocity

    # Two pipes 10 cm apart at 900 MHz (FDTD dev half): their flanks overlap, the survey's hyperbola
    # fits find nothing to use, and the whole survey used to be refused for want of a velocity.
    case = next(c for c in fdtd_cases() if c.name == "two_pipes_900")
    survey = fdtd_survey(case, json.loads((FDTD_DATA / "two_pipes_900.json").read_text()))
    cfg = eval_end_to_end.chain_config(load_config(), survey.gpr, "classical", "geometric")
    processed = {line: preprocess(b, cfg.gpr) for line, b in survey.bscans.items()}
    with pytest.raises(InterpretationError):
        estimate_velocity(list(processed.values()), cfg.gpr, cfg.interpretation)
    found = survey_velocity(processed, cfg)
    v, estimated, hints = found.v, found.estimated, found.hints
    assert estimated and hints == ()
    assert abs(v / survey.true_velocity - 1.0) < 0.1
    # A line too short to interpret (a survey stopped just after it began one) does not refuse the others.
    first = processed[min(processed)]
    stub = dataclasses.replace(first, data=first.data[:2], positions=first.positions[:2], times=first.times[:2],
                               position_std_m=None)
    assert survey_velocity({**processed, max(processed) + 1: stub}, cfg)[0] == pytest.approx(v)


def test_a_line_too_short_to_interpret_is_left_out_of_the_survey_not_the_survey() -> None:
    from gprbot.errors import InterpretationError
    from gprbot.infer.pipeline import reconstruct_survey

    case = next(c for c in fdtd_cases() if c.name == "pvc_air_1600")
    survey = fdtd_survey(case, json.loads((FDTD_DATA / "pvc_air_1600.json").read_text()))
    cfg = eval_end_to_end.chain_config(load_config(), survey.gpr, "classical", "geometric")
    first = survey.bscans[min(survey.bscans)]
    stub = dataclasses.replace(first, data=first.data[:2], positions=first.positions[:2], times=first.times[:2],
                               position_std_m=None)  # a line the robot was stopped on just after it began
    result = reconstruct_survey({**survey.bscans, 99: stub}, cfg, np.random.default_rng(0))
    assert [lr.line for lr in result.lines] == sorted(survey.bscans)
    assert list(result.skipped_lines) == [99] and "2 traces" in result.skipped_lines[99]
    assert len(result.reconstruction.pipes) == 1
    with pytest.raises(InterpretationError, match="no line of the survey could be interpreted: line 99"):
        reconstruct_survey({99: stub}, cfg, np.random.default_rng(0))
