"""Where a fitted pipe may continue: footprint, extension to its edge, distance past the fitted part, cutting."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gprbot.reconstruct.completion import PipeModel
from gprbot.reconstruct.extension import (
    MAX_EXTENSION_M,
    ExtendedAxis,
    arclength_on,
    beyond_fit,
    cut_polyline,
    extend_to_footprint,
    met_extensions,
    rod_candidates,
    seen_extension,
    survey_footprint,
)
from gprbot.reconstruct.register import SliceCloud

FOOTPRINT = (0.0, 2.0, -0.05, 0.95)  # lines along x at y = 0, 0.1, ..., 0.9


def _lines() -> dict[int, np.ndarray]:
    x = np.linspace(0.0, 2.0, 201)
    return {i: np.stack([x, np.full_like(x, 0.1 * i), np.zeros_like(x)], axis=1) for i in range(10)}


def test_the_footprint_is_the_lines_box_widened_by_half_a_spacing_across_them() -> None:
    assert survey_footprint(_lines()) == pytest.approx(FOOTPRINT)


@pytest.mark.parametrize("along_y", [False, True])
def test_lines_wider_apart_than_they_are_long_still_get_half_a_spacing_across_them(along_y: bool) -> None:
    # six lines 0.32 m apart, each 1.37 m long (pose noise of a few mm): the survey spans more across than along
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 1.37, 120)
    lines = {i: np.stack([x + rng.normal(0, 0.003, x.size), np.full_like(x, 0.32 * i) + rng.normal(0, 0.003, x.size),
                          np.zeros_like(x)], axis=1) for i in range(6)}
    if along_y:
        lines = {i: p[:, [1, 0, 2]] for i, p in lines.items()}
    xmin, xmax, ymin, ymax = survey_footprint(lines)
    across = (xmin, xmax) if along_y else (ymin, ymax)
    along = (ymin, ymax) if along_y else (xmin, xmax)
    assert across == pytest.approx((-0.16, 1.76), abs=0.015)
    assert along == pytest.approx((0.0, 1.37), abs=0.015)


def test_a_footprint_needs_a_line() -> None:
    with pytest.raises(ValueError, match="at least one line"):
        survey_footprint({})


def test_a_free_end_runs_on_to_the_footprint_edge_and_a_joined_end_stays() -> None:
    axis = np.array([[1.0, 0.3, -0.2], [1.0, 0.6, -0.2]])  # across the lines, seen on lines 3..6
    free = extend_to_footprint(axis, (None, None), FOOTPRINT)
    assert free.axis[0] == pytest.approx([1.0, -0.05, -0.2])
    assert free.axis[-1] == pytest.approx([1.0, 0.95, -0.2])
    assert free.added == pytest.approx((0.35, 0.35))
    joined = extend_to_footprint(axis, (0, None), FOOTPRINT)
    assert joined.axis[0] == pytest.approx(axis[0]) and joined.added[0] == 0.0


def test_an_oblique_end_runs_along_its_own_direction_and_no_further_than_the_cap() -> None:
    axis = np.array([[1.0, 0.4, -0.2], [1.1, 0.5, -0.2]])  # 45° to the lines
    ext = extend_to_footprint(axis, (None, None), FOOTPRINT)
    end = ext.axis[-1]
    assert end[1] == pytest.approx(0.95) and end[0] - 1.1 == pytest.approx(0.45)
    huge = (-10.0, 10.0, -10.0, 10.0)
    assert max(extend_to_footprint(axis, (None, None), huge).added) == pytest.approx(MAX_EXTENSION_M)


def test_points_past_the_fitted_part_measure_how_far_and_inside_it_zero() -> None:
    axis = np.array([[1.0, 0.3, -0.2], [1.0, 0.6, -0.2]])
    ext = extend_to_footprint(axis, (None, None), FOOTPRINT)
    points = np.array([[1.0, 0.0, -0.2], [1.02, 0.45, -0.21], [1.0, 0.9, -0.2]])
    assert beyond_fit(points, np.zeros(3, dtype=np.int64), [ext]) == pytest.approx([0.3, 0.0, 0.3])


def test_arclength_and_cutting_follow_a_bent_polyline() -> None:
    bend = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    assert arclength_on(np.array([[0.5, 0.1, 0.0], [1.1, 0.5, 0.0]]), bend) == pytest.approx([0.5, 1.5])
    cut = cut_polyline(bend, 0.5, 1.5)
    assert cut == pytest.approx(np.array([[0.5, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.5, 0.0]]))


def test_candidates_cover_the_extended_rods_inside_the_footprint() -> None:
    pipe = PipeModel(axis=np.array([[1.0, 0.3, -0.2], [1.0, 0.6, -0.2]]), radius_m=0.03, depth_of_cover_m=0.17,
                     diameter_m=0.06, confidence=0.9, n_slices=4)
    got = rod_candidates([pipe], FOOTPRINT, 256, 1024, np.random.default_rng(0))
    assert got is not None
    assert got.fit.shape == (256, 3) and got.query.shape == (1024, 3)
    assert np.all(np.abs(got.fit[:, 1] - 0.45) <= 0.15 + 0.03 + 1e-9)
    assert got.query[:, 1].min() < 0.05 and got.query[:, 1].max() > 0.85  # the rod runs on to the edges
    past = got.beyond_m > 0
    assert 0.5 < past.mean() < 0.8  # 0.7 of the 1.0 m rod lies past the fitted 0.3 m
    outside = (-5.0, -4.0, -5.0, -4.0)
    assert rod_candidates([pipe], outside, 256, 1024, np.random.default_rng(0)) is None


def _slices(seen_at: dict[int, float]) -> list[SliceCloud]:
    """Lines along x at y = 0.1 i (i = 0..9), recorded; line i shows a pipe section at x = seen_at[i] (0.2 m deep)."""
    out = []
    for i in range(10):
        points = np.zeros((0, 3)) if i not in seen_at else np.array([[seen_at[i], 0.1 * i, -0.2]])
        out.append(SliceCloud(line=i, points=points, direction=np.array([1.0, 0.0]),
                              track_xy=np.array([[0.0, 0.1 * i], [2.0, 0.1 * i]])))
    return out


def test_a_continued_pipe_stops_past_two_recorded_lines_in_a_row_that_saw_nothing_there() -> None:
    axis = np.array([[1.0, 0.3, -0.2], [1.0, 0.6, -0.2]])  # seen on lines 3..6, pushed on to y = -0.05 and 0.95
    pushed = extend_to_footprint(axis, (None, None), FOOTPRINT)
    # below, lines 2 and 1 show nothing at x = 1: cut half-way between them; above, line 7 misses it (an
    # interpreter's miss) and lines 8 and 9 see it again: it runs on to the edge
    cut = seen_extension(pushed, 0.02, _slices({3: 1.0, 4: 1.0, 5: 1.0, 6: 1.0, 8: 1.0, 9: 1.01}))
    assert cut.axis[0] == pytest.approx([1.0, 0.15, -0.2])
    assert cut.axis[-1] == pytest.approx([1.0, 0.95, -0.2])
    assert cut.added == pytest.approx((0.15, 0.35))


def test_lines_that_see_something_elsewhere_or_were_not_recorded_do_not_count_as_seeing_the_pipe() -> None:
    axis = np.array([[1.0, 0.3, -0.2], [1.0, 0.6, -0.2]])
    pushed = extend_to_footprint(axis, (None, None), FOOTPRINT)
    elsewhere = seen_extension(pushed, 0.02, _slices({1: 1.5, 2: 1.5, 7: 0.3, 8: 0.3}))  # 0.5-0.7 m to the side
    assert elsewhere.added == pytest.approx((0.15, 0.15))
    unrecorded = [replace(s, track_xy=None) for s in _slices({})]  # tracks unknown: nothing to go by
    assert seen_extension(pushed, 0.02, unrecorded) == pushed


def _pushed(fitted: list[tuple[float, float, float]], tip: tuple[float, float, float]) -> ExtendedAxis:
    """A fitted straight axis pushed on at its end to `tip`."""
    axis = np.array([*fitted[:-1], tip], dtype=np.float64)
    return ExtendedAxis(axis, (0.0, float(np.linalg.norm(np.subtract(tip, fitted[-1])))))


def test_two_pushed_on_legs_that_meet_stop_at_the_corner() -> None:
    up = _pushed([(0.0, 0.0, -0.3), (0.0, 1.2, -0.3)], (0.0, 2.0, -0.3))
    across = _pushed([(1.5, 1.5, -0.3), (0.3, 1.5, -0.3)], (-0.5, 1.5, -0.3))
    cut = met_extensions([up, across], [0.02, 0.02])
    assert cut[0].added[1] == pytest.approx(0.3, abs=1e-6)
    assert cut[1].added[1] == pytest.approx(0.3, abs=1e-6)
    np.testing.assert_allclose(cut[0].axis[-1], [0.0, 1.5, -0.3], atol=1e-6)
    np.testing.assert_allclose(cut[1].axis[-1], [0.0, 1.5, -0.3], atol=1e-6)


def test_a_pushed_on_end_stops_on_a_pipe_it_runs_into() -> None:
    up = _pushed([(0.0, 0.0, -0.3), (0.0, 1.2, -0.3)], (0.0, 2.0, -0.3))
    main = ExtendedAxis(np.array([[-1.0, 1.6, -0.31], [1.0, 1.6, -0.31]]), (0.0, 0.0))
    cut = met_extensions([up, main], [0.02, 0.03])
    assert cut[0].added[1] == pytest.approx(0.4, abs=1e-6)
    assert cut[1] is main


def test_pipes_side_by_side_or_crossing_deeper_do_not_meet() -> None:
    up = _pushed([(0.0, 0.0, -0.3), (0.0, 1.2, -0.3)], (0.0, 2.0, -0.3))
    beside = _pushed([(0.05, 0.0, -0.3), (0.05, 1.2, -0.3)], (0.05, 2.0, -0.3))
    deeper = ExtendedAxis(np.array([[-1.0, 1.6, -0.8], [1.0, 1.6, -0.8]]), (0.0, 0.0))
    cut = met_extensions([up, beside, deeper], [0.02, 0.02, 0.03])
    assert [c.added for c in cut] == [up.added, beside.added, deeper.added]
