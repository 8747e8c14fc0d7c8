"""The shipped completion models against models/EVAL.md: the committed ONNX files re-run on regenerated samples.

The evaluation (python -m training.evaluate) records every test sample's CD2 for each model and for two
baselines — the sparse input returned as the answer, and the geometric fit — and EVAL.md states each
model's standing against them: on how many samples its CD2 is lower, and whether its mean and its median
are (for GPRNet: better than its input by the mean, worse by the median, worse than the fit by both).
Here the first test samples are regenerated from their seeds, the committed models run on them and both
baselines computed afresh. On every regenerated sample each model's CD2, and so its standing against each
baseline, must be the recorded one; and EVAL.md must be exactly what the recorded rows render to. A model
retrained or re-exported without re-running the evaluation, a baseline whose code changed, or a figure or
sentence edited by hand, fails.
"""

from __future__ import annotations

import json
import re
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("torch")

from gprbot.infer.gprnet import INPUT_NAME, GprnetCompletion
from training import evaluate
from training.chamfer import cloud_metrics
from training.pointcloud_data import CompletionSample, make_sample
from training.random_scenes import split_seeds

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"
REPORT = MODELS / "eval_completion.json"
CHECKED_SAMPLES = 4


def _report() -> dict[str, Any]:
    if not REPORT.exists():
        pytest.skip("models/eval_completion.json not written yet (python -m training.evaluate)")
    return dict(json.loads(REPORT.read_text()))


def _scored_models() -> list[str]:
    if not REPORT.exists():
        return []
    per_sample = json.loads(REPORT.read_text())["per_sample"]
    return [n for n in per_sample if n not in (*evaluate.BASELINES, "fit_refiner") and (MODELS / f"{n}.onnx").exists()]


@cache
def _samples() -> tuple[CompletionSample, ...]:
    samples = tuple(s for s in map(make_sample, split_seeds("test")[:CHECKED_SAMPLES]) if s is not None)
    assert len(samples) == CHECKED_SAMPLES
    return samples


@cache
def _baselines() -> dict[str, dict[int, float]]:
    """Each baseline's CD2 on the regenerated samples, computed here and now."""
    samples = _samples()
    data = {"seed": np.array([s.seed for s in samples]), "sparse": np.stack([s.sparse for s in samples]),
            "centre": np.stack([s.centre for s in samples]), "scale": np.array([s.scale for s in samples])}
    geometric = evaluate.geometric_prediction(data, [])
    return {"sparse_copy": {s.seed: cloud_metrics(s.sparse, s.dense).cd2 for s in samples},
            "geometric": {s.seed: cloud_metrics(geometric(i), s.dense).cd2 for i, s in enumerate(samples)}}


def _recorded(name: str) -> dict[int, dict[str, float]]:
    return {r["seed"]: r for r in _report()["per_sample"][name]}


def test_every_scored_model_is_committed() -> None:
    report = _report()
    # NAME_sK: the other training seeds of a compared model, scored from training/checkpoints (13 MB each)
    for name in (n for n in report["latency"] if not re.fullmatch(r".+_s\d+", n)):
        assert (MODELS / f"{name}.onnx").exists(), f"EVAL.md scores models/{name}.onnx, which is not committed"
        assert (MODELS / f"{name}.json").exists(), f"models/{name}.onnx has no model card"


@pytest.mark.parametrize("baseline", evaluate.BASELINES)
def test_the_baselines_are_reproduced(baseline: str) -> None:
    recorded = _recorded(baseline)
    for seed, cd2 in _baselines()[baseline].items():
        assert cd2 == pytest.approx(recorded[seed]["cd2"], rel=1e-3), f"{baseline} seed {seed}: CD2 differs from EVAL"


@pytest.mark.parametrize("name", _scored_models())
def test_each_model_keeps_its_recorded_figures_and_standing(name: str) -> None:
    recorded = _recorded(name)
    model = GprnetCompletion(MODELS / f"{name}.onnx", threads=2)
    for sample in _samples():
        outputs, _ = model.model.run({INPUT_NAME: sample.sparse[None]})
        dense = np.asarray(outputs["dense_points"][0])
        assert dense.shape == (8064, 3) and np.all(np.isfinite(dense))
        m = cloud_metrics(dense, sample.dense)
        assert m.cd2 == pytest.approx(recorded[sample.seed]["cd2"], rel=1e-3), f"{name} seed {sample.seed}: CD2"
        assert m.fscore == pytest.approx(recorded[sample.seed]["fscore"], abs=2e-3)
        for baseline, live in _baselines().items():
            was_lower = recorded[sample.seed]["cd2"] < _recorded(baseline)[sample.seed]["cd2"]
            assert (m.cd2 < live[sample.seed]) == was_lower, f"{name} vs {baseline}, seed {sample.seed}"


def test_the_refiner_keeps_its_recorded_figures() -> None:
    """The FitRefiner through the runtime's refined completion on the same regenerated samples."""
    if "fit_refiner" not in _report()["per_sample"]:  # type: ignore[operator]
        pytest.skip("EVAL.md does not score models/fit_refiner.onnx")
    recorded = _recorded("fit_refiner")
    samples = _samples()
    data = {"seed": np.array([s.seed for s in samples]), "sparse": np.stack([s.sparse for s in samples]),
            "centre": np.stack([s.centre for s in samples]), "scale": np.array([s.scale for s in samples])}
    predict = evaluate.refined_prediction(data, MODELS / "fit_refiner.onnx")
    for i, sample in enumerate(samples):
        m = cloud_metrics(predict(i), sample.dense)
        assert m.cd2 == pytest.approx(recorded[sample.seed]["cd2"], rel=1e-3), f"fit_refiner seed {sample.seed}: CD2"


def test_eval_md_states_what_the_recorded_rows_give() -> None:
    report = _report()
    text = (MODELS / "EVAL.md").read_text()
    for line in evaluate.standing_lines(report):
        assert line in text, f"EVAL.md lacks {line!r}: re-render it (python -m training.evaluate)"
    assert text == evaluate.markdown(report), "EVAL.md is not what eval_completion.json renders to"
    assert "degraded **truth masks**" in text.split("## Table I")[0]  # the header says what feeds the models
