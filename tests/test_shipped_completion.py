"""The shipped completion models: each loads through the runtime, and models/EVAL.md's figures are theirs.

The evaluation (python -m training.evaluate) records every test sample's metrics in
models/eval_completion.json; here the first test samples are regenerated from their seeds, run through
the committed ONNX files and scored again — a model retrained or exported without re-running the
evaluation, or a figure edited by hand, fails.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gprbot.infer.gprnet import INPUT_NAME, GprnetCompletion
from training.chamfer import cloud_metrics
from training.pointcloud_data import make_sample
from training.random_scenes import split_seeds

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"
REPORT = MODELS / "eval_completion.json"
CHECKED_SAMPLES = 3


def _report() -> dict[str, object]:
    if not REPORT.exists():
        pytest.skip("models/eval_completion.json not written yet (python -m training.evaluate)")
    return dict(json.loads(REPORT.read_text()))


def _scored_models() -> list[str]:
    if not REPORT.exists():
        return []
    return [n for n in json.loads(REPORT.read_text())["per_sample"] if (MODELS / f"{n}.onnx").exists()]


def test_every_scored_model_is_committed() -> None:
    report = _report()
    for name in report["latency"]:  # type: ignore[attr-defined]
        assert (MODELS / f"{name}.onnx").exists(), f"EVAL.md scores models/{name}.onnx, which is not committed"
        assert (MODELS / f"{name}.json").exists(), f"models/{name}.onnx has no model card"


@pytest.mark.parametrize("name", _scored_models())
def test_recorded_test_metrics_are_reproduced_by_the_committed_model(name: str) -> None:
    rows = {r["seed"]: r for r in _report()["per_sample"][name]}  # type: ignore[index]
    model = GprnetCompletion(MODELS / f"{name}.onnx", threads=2)
    seeds = [s for s in split_seeds("test") if s in rows][:CHECKED_SAMPLES]
    assert len(seeds) == CHECKED_SAMPLES
    for seed in seeds:
        sample = make_sample(seed)
        assert sample is not None
        outputs, _ = model.model.run({INPUT_NAME: sample.sparse[None]})
        dense = np.asarray(outputs["dense_points"][0])
        assert dense.shape == (8064, 3) and np.all(np.isfinite(dense))
        m = cloud_metrics(dense, sample.dense)
        assert m.cd2 == pytest.approx(rows[seed]["cd2"], rel=1e-3), f"{name} seed {seed}: CD2 differs from EVAL"
        assert m.fscore == pytest.approx(rows[seed]["fscore"], abs=2e-3)


def test_shipped_gprnet_beats_copying_its_input() -> None:
    """A trained completion is far closer to the pipes than its sparse slices are; an untrained one is not."""
    report = _report()
    table = report["table1"]  # type: ignore[index]
    assert table["gprnet"]["all"]["cd2_e3"] < table["sparse_copy"]["all"]["cd2_e3"]
