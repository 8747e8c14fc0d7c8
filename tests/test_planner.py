"""Survey planner: boustrophedon geometry, never rotating, settle at line ends."""

from __future__ import annotations

import numpy as np
import pytest

from gprbot.config import SurveyConfig
from gprbot.errors import ConfigError
from gprbot.motion.planner import plan_survey


def test_lines_alternate_direction_and_step_sideways() -> None:
    cfg = SurveyConfig(lines=4, spacing_m=0.2, length_m=1.5, speed_m_s=0.25, settle_s=0.5, start_xy_m=(1.0, 2.0))
    plan = plan_survey(cfg)
    lines = plan.lines()
    assert [s.line for s in lines] == [0, 1, 2, 3]
    for i, s in enumerate(lines):
        assert s.start_xy[1] == pytest.approx(2.0 + 0.2 * i)
        assert s.end_xy[1] == pytest.approx(s.start_xy[1])  # a line never drifts sideways
        assert s.end_xy[0] - s.start_xy[0] == pytest.approx(1.5 if i % 2 == 0 else -1.5)
        assert s.t_end - s.t_start == pytest.approx(1.5 / 0.25)
    # Time adds up: 4 lines, 3 steps, and a settle before, after each line and after each step.
    assert plan.duration_s == pytest.approx(4 * 6.0 + 3 * 0.8 + (1 + 4 + 3) * 0.5)


def test_every_segment_is_axis_aligned_translation() -> None:
    plan = plan_survey(SurveyConfig(lines=5))
    for s in plan.segments:
        d = s.end_xy - s.start_xy
        assert d[0] == 0.0 or d[1] == 0.0  # forward, backward or sideways — no diagonal, no turn
        if s.kind == "settle":
            assert np.all(s.velocity == 0)


def test_position_and_velocity_at_times() -> None:
    cfg = SurveyConfig(lines=2, spacing_m=0.1, length_m=1.0, speed_m_s=0.5, settle_s=1.0)
    plan = plan_survey(cfg)
    line0 = plan.lines()[0]
    mid = 0.5 * (line0.t_start + line0.t_end)
    assert plan.position(np.array([mid]))[0] == pytest.approx([0.5, 0.0])
    assert plan.velocity(np.array([mid]))[0] == pytest.approx([0.5, 0.0])
    assert plan.position(np.array([1e6]))[0] == pytest.approx([0.0, 0.1])  # clamped at the end


@pytest.mark.parametrize(
    ("kwargs", "key"), [({"lines": 0}, "survey.lines"), ({"speed_m_s": 0.0}, "survey.speed_m_s"),
                        ({"lines": 2, "spacing_m": -0.1}, "survey.spacing_m")]
)
def test_bad_plans_name_the_key(kwargs: dict[str, float], key: str) -> None:
    with pytest.raises(ConfigError, match=key):
        plan_survey(SurveyConfig(**kwargs))  # type: ignore[arg-type]
