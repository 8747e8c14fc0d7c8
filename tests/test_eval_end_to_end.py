"""The end-to-end evaluation on one held-out scene: four chains, scored against the scene's truth."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")

from gprbot.config import load_config
from training import eval_end_to_end
from training.pointcloud_data import make_sample
from training.random_scenes import split_seeds


def test_one_scene_through_every_chain() -> None:
    sample = make_sample(split_seeds("test")[0])
    assert sample is not None
    data = {"seed": np.array([sample.seed]), "case": np.array([sample.case]), "centre": sample.centre[None],
            "scale": np.array([sample.scale]), "dense": sample.dense[None]}
    rows = eval_end_to_end.evaluate_scene(0, data, load_config(), 1)
    chains = {(r["interpretation"], r["completion"]) for r in rows}
    assert chains == {(m, c) for m in eval_end_to_end.INTERPRETERS for c in eval_end_to_end.COMPLETIONS}
    by_chain = {(r["interpretation"], r["completion"]): r for r in rows}
    classical = by_chain["classical", "geometric"]
    assert classical["found"] >= 1 and abs(classical["velocity_err_rel"]) < 0.1
    assert classical["cd2"] < 5e-3  # a found pipe's cylinder lies far closer to the truth than a blob
    # pipes.json comes from the fit through the slices whichever completion makes the dense cloud
    assert by_chain["classical", "gprnet"]["horizontal_m"] == classical["horizontal_m"]
    summary = eval_end_to_end.summarise(rows)
    assert 0.0 < summary["pipe_recall"] <= 1.0
    result = {"scenes": 1, "failures": [], "median_abs_velocity_err_pct": 1.0, "rows": rows,
              "chains": {"classical + geometric": {"all": eval_end_to_end.summarise([classical])}},
              "median_interpret_s_per_scene": {"classical": 1.0}}
    assert "| classical + geometric |" in eval_end_to_end.markdown(result, "cmd")
