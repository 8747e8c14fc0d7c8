"""Truth comparison: matching found pipes to a scene's pipes and measuring their errors."""

from __future__ import annotations

import numpy as np
import pytest

from gprbot.reconstruct.completion import PipeModel
from gprbot.sim.scene import load_scene
from gprbot.simulated.evaluation import compare_to_truth, format_truth_table, within_bounds


def _model(axis: np.ndarray, radius: float) -> PipeModel:
    depth = float(-axis[:, 2].max())
    return PipeModel(axis, radius, depth - radius, 2 * radius, 0.9, 10)


def test_exact_pipes_match_with_zero_error_and_offsets_are_measured() -> None:
    scene = load_scene("paper_slab")
    region = (0.0, 2.0, 0.0, 0.9)
    found = []
    for p in scene.pipes:
        axis = p.points.copy()
        axis[:, 0] += 0.02  # 2 cm east
        axis[:, 2] -= 0.01  # 1 cm deeper
        found.append(_model(axis, p.radius_m * 1.1))
    matches, extras = compare_to_truth(found, scene, region)
    assert not extras
    assert len(matches) == len(scene.pipes)
    for m in matches:
        assert m.found is not None
        assert m.horizontal_err_m == pytest.approx(0.02, abs=1e-3)
        assert m.depth_err_m == pytest.approx(0.01, abs=1e-3)
        assert m.diameter_err_rel == pytest.approx(0.1, abs=1e-6)
    assert within_bounds(matches)
    assert "MISSED" not in format_truth_table(matches, extras, found)


def test_missed_and_extra_pipes_are_reported() -> None:
    scene = load_scene("paper_slab")
    far = np.array([[5.0, 0.0, -0.2], [5.0, 1.0, -0.2]])
    matches, extras = compare_to_truth([_model(far, 0.02)], scene, (0.0, 2.0, 0.0, 0.9))
    assert all(m.found is None for m in matches)
    assert extras == [0]
    assert not within_bounds(matches)
    table = format_truth_table(matches, extras, [_model(far, 0.02)])
    assert "MISSED" in table and "(extra)" in table
