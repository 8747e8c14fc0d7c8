"""What one hyperbola can show of a pipe's radius and of the velocity (validation.hyperbola_signatures)."""

from __future__ import annotations

import pytest

from validation.hyperbola_signatures import Geometry, centre_ray_time, radius_signature, velocity_signature

PERIOD_NS = 1000.0 / 1600.0  # 1.6 GHz


def _pipe(height_m: float) -> Geometry:
    return Geometry(0.5, 0.16, 0.04, 0.1, height_m, 0.05, PERIOD_NS)  # a 4 cm pipe, top 12 cm down


def test_a_point_on_the_centre_ray_is_the_straight_ray_time_at_height_zero() -> None:
    import numpy as np

    x = np.array([0.5, 0.6])
    t = centre_ray_time(x, 0.5, 0.16, 0.04, 0.1, 0.0, 0.0)
    assert t == pytest.approx([2 * 0.12 / 0.1, 2 * (np.hypot(0.1, 0.16) - 0.04) / 0.1])


def test_an_antenna_above_the_ground_hides_the_radius_a_ground_coupled_one_shows() -> None:
    coupled, _ = radius_signature(_pipe(0.0))
    raised, top = radius_signature(_pipe(0.03))
    assert coupled > 0.2  # periods: a curve fit can tell this pipe from a point
    assert raised < 0.05  # the air leg takes the moveout: it cannot
    assert top == pytest.approx(0.12, abs=0.003)  # and both share the top


def test_with_the_radius_free_a_velocity_5_percent_off_fits_as_well() -> None:
    assert velocity_signature(_pipe(0.0), radius_known=True) > 0.1
    assert velocity_signature(_pipe(0.0), radius_known=False) < 0.05
