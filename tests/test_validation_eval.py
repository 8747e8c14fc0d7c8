"""The evaluation's scoring rules, and the chain held to what it measures on the yardsticks (regression tests).

The figures asserted here are those of validation/REPORT.md for the same cases; the FDTD cases are
dev-half scenes (the test half is only reported, never asserted on, so nothing is tuned to it).
"""

from __future__ import annotations

import pytest

from validation.cases import REAL_DATA, fdtd_cases, real_cases
from validation.evaluate import run_case
from validation.scoring import Found, Target, match, score


def test_scoring_counts_rebars_reported_as_rebars_as_not_false() -> None:
    truth = [Target(0.5, 0.2, 0.02, "pipe"), Target(0.1, 0.05, 0.006, "rebar"), Target(0.3, 0.05, 0.006, "rebar")]
    found = [Found(0.505, 0.195, 0.021, "pipe"), Found(0.1, 0.05, 0.006, "rebar"), Found(0.3, 0.05, 0.006, "pipe"),
             Found(0.9, 0.3, 0.02, "pipe")]
    s = score(found, truth)
    assert (s.pipes, s.pipes_within, s.pipes_within_fine, s.radius_ok, s.tops_within_fine) == (1, 1, 1, 1, 1)
    assert s.false_pipes == 2  # the bar reported as a pipe, and the pipe where there is nothing
    assert (s.rebars, s.rebars_found, s.false_rebars) == (2, 1, 0)


def test_a_right_top_with_a_wrong_radius_counts_as_a_top_not_a_centre() -> None:
    truth = [Target(0.5, 0.2, 0.05, "pipe")]  # top at 0.15
    s = score([Found(0.5, 0.16, 0.01, "pipe")], truth)  # top 0.15, centre 4 cm high
    assert (s.pipes_within, s.pipes_within_fine, s.tops_within_fine, s.tops_within, s.false_pipes) == (0, 0, 1, 1, 1)
    far = score([Found(0.5, 0.20, 0.01, "pipe")], truth)  # centre right, top 4 cm low: found at the centre only
    assert (far.pipes_within, far.tops_within) == (1, 0)


def test_a_radius_is_judged_apart_where_the_method_claims_to_have_measured_it() -> None:
    truth = [Target(0.2, 0.2, 0.02, "pipe"), Target(0.5, 0.2, 0.05, "pipe"), Target(0.8, 0.2, 0.03, "pipe")]
    found = [Found(0.2, 0.2, 0.021, "pipe", radius_measured=True),  # claimed and right
             Found(0.5, 0.2, 0.02, "pipe", radius_measured=True),  # claimed and wrong
             Found(0.8, 0.2, 0.03, "pipe"),  # right, but not claimed
             Found(1.5, 0.2, 0.03, "pipe", radius_measured=True)]  # a false pipe: no radius to judge
    s = score(found, truth)
    assert (s.radius_ok, s.radius_claimed, s.radius_claimed_ok) == (2, 2, 1)


def test_matching_is_one_to_one_and_nearest_first() -> None:
    truth = [Target(0.50, 0.2, None, "pipe"), Target(0.53, 0.2, None, "pipe")]
    found = [Found(0.52, 0.2, 0.0, "pipe")]
    assert match(found, truth, 0.03) == {1: 0}
    assert score([Found(0.5, 0.235, 0.02, "pipe")], truth[:1]).pipes_within == 0  # depth off by 3.5 cm


def _case(name: str):  # type: ignore[no-untyped-def]
    cases = [c for c in fdtd_cases() + real_cases() if c.name == name or c.name.startswith(name)]
    if not cases:
        pytest.skip(f"{name} is not available here")
    return cases[0]


@pytest.mark.skipif(not REAL_DATA.exists(), reason="shared/data/real is not beside the checkout")
def test_real_structurescan_line_gives_its_seven_bars_as_rebars() -> None:
    row = run_case(_case("ssmini File____002"), "chain", "estimated")
    hits = match(row.outcome.found, row.case.targets, row.case.tolerance_m)
    assert len(hits) == 7
    assert len(row.outcome.found) - len(hits) <= 1
    assert all(row.outcome.found[j].kind == "rebar" for j in hits.values())


@pytest.mark.parametrize("name", ["pvc_air_1600", "debye_1600", "random_11"])
def test_fdtd_dev_pipes_within_a_centimetre_at_the_true_velocity(name: str) -> None:
    row = run_case(_case(name), "chain", "given")
    assert row.case.group == "fdtd-dev"
    assert row.score.pipes_within_fine == row.score.pipes
    assert row.score.false_pipes == 0


def test_fdtd_dev_rebars_reported_as_rebars() -> None:
    row = run_case(_case("random_11"), "chain", "given")
    assert row.score.rebars_found == row.score.rebars == 3


def test_fdtd_slab_without_pipes_gives_nothing() -> None:
    row = run_case(_case("no_pipe_2000"), "chain", "estimated")
    assert row.outcome.found == ()
    assert not row.outcome.velocity_estimated  # nothing to measure it on, and it says so


@pytest.mark.skipif(not REAL_DATA.exists(), reason="shared/data/real is not beside the checkout")
def test_real_structurescan_line_with_two_rows_gives_all_five_targets() -> None:
    # Each shallow bar's hyperbola overlaps a deeper one's 6 cm beside it: the picks merge them, the
    # migrated image's spots separate them.
    row = run_case(_case("ssmini File____001"), "chain", "estimated")
    hits = match(row.outcome.found, row.case.targets, row.case.tolerance_m)
    assert len(hits) == 5
    assert len(row.outcome.found) - len(hits) <= 1


def test_fdtd_dev_pipe_under_a_rebar_mesh_is_found_and_the_mesh_is_rebar() -> None:
    row = run_case(_case("rebar_pipe_1200"), "chain", "given")
    assert row.score.pipes_within == row.score.pipes == 1
    assert row.score.rebars_found >= 4
    assert row.score.false_pipes <= 1


@pytest.mark.skipif(not REAL_DATA.exists(), reason="shared/data/real is not beside the checkout")
def test_real_trench_line_velocity_from_its_deep_hyperbolas_not_the_surface_zone() -> None:
    # The near-surface zone of this 26 m field line is 20-50x brighter than the diffractors at 10-40 ns;
    # ranked by amplitude it took every velocity vote (0.227 m/ns). The fill's published velocity is 0.165.
    row = run_case(_case("SU trench"), "chain", "estimated")
    assert row.outcome.velocity_estimated
    assert abs(row.outcome.velocity / 0.165 - 1.0) <= 0.05
    assert len(match(row.outcome.found, row.case.targets, row.case.tolerance_m)) >= 2
    # One diffractor is one detection: its migrated spot and its fitted apex lie a trace (4 cm) or so apart.
    found = row.outcome.found
    assert not any(abs(a.x_m - b.x_m) <= 0.08 and abs(a.depth_m - b.depth_m) <= 0.03
                   for i, a in enumerate(found) for b in found[i + 1:])
