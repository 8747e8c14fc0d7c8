"""Truth comparison: matching found pipes to a scene's pipes and measuring their errors."""

from __future__ import annotations

import numpy as np
import pytest

from gprbot.reconstruct.completion import PipeModel
from gprbot.sim.scene import load_scene
from gprbot.simulated.evaluation import MIN_COVERAGE, compare_to_truth, format_truth_table, within_bounds


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


def _pieces(y0: float, y1: float, dx: float = 0.0) -> list[PipeModel]:
    """Each paper_slab pipe found only between y0 and y1 (its true x, depth and radius; shifted dx east)."""
    out = []
    for p in load_scene("paper_slab").pipes:
        x, z = p.points[0, 0] + dx, p.points[0, 2]
        out.append(_model(np.array([[x, y0, z], [x, y1, z]]), p.radius_m))
    return out


def test_a_stub_lying_on_a_pipe_is_a_miss_and_an_extra() -> None:
    scene = load_scene("paper_slab")
    stubs = _pieces(0.40, 0.50)  # 10 cm of each pipe's 90 cm in the survey
    matches, extras = compare_to_truth(stubs, scene, (0.0, 2.0, 0.0, 0.9))
    assert all(m.found is None for m in matches)
    # followed within 5 cm of either end too: 20 cm of 90
    assert [m.partial for m in matches] == [0, 1, 2, 3]
    assert all(m.coverage == pytest.approx(0.2 / 0.9, abs=0.02) for m in matches)
    assert extras == [0, 1, 2, 3]
    assert not within_bounds(matches)
    table = format_truth_table(matches, extras, stubs)
    assert table.count("MISSED") == 4 and "lies along steel_60 but follows too little" in table


def test_a_full_length_found_pipe_is_a_hit() -> None:
    scene = load_scene("paper_slab")
    found = _pieces(-0.05, 0.95)
    matches, extras = compare_to_truth(found, scene, (0.0, 2.0, 0.0, 0.9))
    assert [m.found for m in matches] == [0, 1, 2, 3] and not extras
    assert all(m.coverage == pytest.approx(1.0) for m in matches)
    assert within_bounds(matches)


def test_found_needs_most_of_the_surveyed_length() -> None:
    scene = load_scene("paper_slab")
    region = (0.0, 2.0, 0.0, 0.9)
    short, _ = compare_to_truth(_pieces(0.0, 0.35), scene, region)  # 40 cm of 90 followed
    long, _ = compare_to_truth(_pieces(0.0, 0.50), scene, region)  # 55 cm of 90
    assert all(m.found is None and m.coverage < MIN_COVERAGE for m in short)
    assert all(m.found is not None and m.coverage > MIN_COVERAGE for m in long)


def test_a_parallel_axis_beside_the_pipe_is_not_found() -> None:
    scene = load_scene("paper_slab")
    matches, extras = compare_to_truth(_pieces(-0.05, 0.95, dx=0.10), scene, (0.0, 2.0, 0.0, 0.9))
    # 10 cm east lies along the pipe (mean under 15 cm) but never within 5 cm of it
    assert all(m.found is None and m.partial is not None and m.coverage == 0.0 for m in matches)
    assert len(extras) == 4


def test_a_second_copy_of_a_found_pipe_is_an_extra() -> None:
    scene = load_scene("paper_slab")
    found = [*_pieces(-0.05, 0.95)[:1], *_pieces(-0.05, 0.95, dx=0.01)[:1]]  # steel_60 found twice, 1 cm apart
    matches, extras = compare_to_truth(found, scene, (0.0, 2.0, 0.0, 0.9))
    assert [m.found for m in matches] == [0, None, None, None] and extras == [1]
