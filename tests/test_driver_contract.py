"""The one driver contract: every driver starts, closes and reports a typed health; one backoff."""

from __future__ import annotations

import inspect
import typing

import pytest

from gprbot.backoff import Backoff
from gprbot.drivers.contract import LinkState, link_state
from gprbot.drivers.gpr.driver import GprDriver
from gprbot.drivers.health import DriverHealth
from gprbot.drivers.motors.driver import MotorDriver
from gprbot.drivers.realsense.driver import RealsenseDriver


@pytest.mark.parametrize("driver", [MotorDriver, GprDriver, RealsenseDriver])
def test_every_driver_starts_closes_and_reports_a_typed_health(driver: type) -> None:
    for name in ("start", "close"):
        assert inspect.iscoroutinefunction(getattr(driver, name)), f"{driver.__name__}.{name}"
    assert typing.get_type_hints(driver.health)["return"] is DriverHealth


def test_backoff_doubles_to_its_longest_and_starts_over_after_a_success() -> None:
    backoff = Backoff(0.1, 0.5)
    assert [backoff.next_s() for _ in range(5)] == [0.1, 0.2, 0.4, 0.5, 0.5]
    backoff.reset()
    assert backoff.next_s() == 0.1


def test_the_camera_is_one_link_over_its_streams() -> None:
    from gprbot.config import RealsenseConfig

    camera = RealsenseDriver(RealsenseConfig())
    assert set(camera.streams()) == {"gyro", "accel", "depth", "color"}
    health = camera.health()
    assert health.name == "realsense" and link_state(health) is LinkState.DOWN  # not started
