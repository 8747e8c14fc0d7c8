"""The radius-velocity law the velocity diagnostics print: a point focus matches a cylinder's apex at v·√(1 + R/d)."""

from __future__ import annotations

import numpy as np
import pytest

from gprbot.gpr.chain.geometry import cylinder_time
from validation.velocity_votes import predicted_vote


@pytest.mark.parametrize(("top", "radius"), [(0.04, 0.06), (0.15, 0.03), (0.30, 0.006)])
def test_point_diffractor_at_the_predicted_velocity_has_the_cylinders_apex_time_and_curvature(
    top: float, radius: float
) -> None:
    v = 0.12
    v_point = predicted_vote(v, top, radius)
    depth_point = top * v_point / v  # the same apex time
    x = np.array([-0.004, 0.0, 0.004])
    cylinder = cylinder_time(x, 0.0, top + radius, radius, v, 0.0, 0.0)
    point = cylinder_time(x, 0.0, depth_point, 0.0, v_point, 0.0, 0.0)
    assert point[1] == pytest.approx(cylinder[1], rel=1e-9)
    curvature = lambda t: (t[0] - 2.0 * t[1] + t[2]) / 0.004**2  # noqa: E731
    assert curvature(point) == pytest.approx(curvature(cylinder), rel=0.01)
    assert v_point > v  # a cylinder always votes fast: the larger and shallower, the faster
