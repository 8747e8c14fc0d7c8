"""Jog controller: duration, deadman, stop and speed limits, all on an injected clock."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gprbot.errors import GprbotError
from gprbot.motion.jog import JogController, JogError, JogStop


def test_jog_runs_for_its_duration_then_stops() -> None:
    jog = JogController(max_speed_m_s=0.3, deadman_timeout_s=0.5)
    jog.jog(0.1, -0.05, duration_s=2.0, now=10.0)
    for k in range(20):  # fed every 0.1 s
        now = 10.0 + 0.1 * k
        assert jog.feed(now)
        np.testing.assert_array_equal(jog.update(now), [0.1, -0.05])
    np.testing.assert_array_equal(jog.update(11.999), [0.1, -0.05])
    np.testing.assert_array_equal(jog.update(12.0), [0.0, 0.0])
    assert not jog.active
    assert jog.last_stop is JogStop.DURATION


def test_deadman_stops_when_feeding_lapses_and_is_not_revived() -> None:
    jog = JogController(deadman_timeout_s=0.5)
    jog.jog(0.0, 0.2, duration_s=10.0, now=0.0)
    assert jog.feed(0.4)
    np.testing.assert_array_equal(jog.update(0.899), [0.0, 0.2])
    np.testing.assert_array_equal(jog.update(0.9), [0.0, 0.0])  # 0.5 s after the last feed
    assert jog.last_stop is JogStop.DEADMAN
    assert not jog.feed(0.95)
    np.testing.assert_array_equal(jog.update(1.0), [0.0, 0.0])


def test_late_feed_reports_the_lapse_even_without_an_update() -> None:
    jog = JogController(deadman_timeout_s=0.5)
    jog.jog(0.1, 0.0, duration_s=10.0, now=0.0)
    assert not jog.keepalive(0.7)
    assert jog.last_stop is JogStop.DEADMAN
    np.testing.assert_array_equal(jog.update(0.7), [0.0, 0.0])


def test_stop_is_immediate() -> None:
    jog = JogController()
    jog.jog(0.1, 0.0, duration_s=5.0, now=0.0)
    np.testing.assert_array_equal(jog.update(0.1), [0.1, 0.0])
    np.testing.assert_array_equal(jog.stop(0.15), [0.0, 0.0])
    np.testing.assert_array_equal(jog.update(0.15), [0.0, 0.0])
    assert jog.last_stop is JogStop.STOPPED


def test_speed_is_limited_keeping_direction_and_duration_capped() -> None:
    jog = JogController(max_speed_m_s=0.3, deadman_timeout_s=100.0, max_duration_s=5.0)
    granted = jog.jog(0.6, 0.8, duration_s=30.0, now=0.0)
    np.testing.assert_allclose(granted, [0.18, 0.24])
    assert math.hypot(*jog.update(1.0)) == pytest.approx(0.3)
    np.testing.assert_array_equal(jog.update(5.0), [0.0, 0.0])
    assert jog.last_stop is JogStop.DURATION


def test_new_jog_replaces_the_running_one() -> None:
    jog = JogController(deadman_timeout_s=2.0)
    jog.jog(0.1, 0.0, duration_s=1.0, now=0.0)
    jog.jog(0.0, -0.1, duration_s=1.0, now=0.3)
    assert jog.last_stop is JogStop.REPLACED
    np.testing.assert_array_equal(jog.update(1.2), [0.0, -0.1])  # the first would have ended at 1.0


@pytest.mark.parametrize("args", [(math.nan, 0.0, 1.0), (0.1, math.inf, 1.0), (0.1, 0.0, -1.0)])
def test_bad_jog_is_rejected_with_a_gprbot_error(args: tuple[float, float, float]) -> None:
    jog = JogController()
    with pytest.raises(JogError) as info:
        jog.jog(*args, now=0.0)
    assert isinstance(info.value, GprbotError)
    assert not jog.active
