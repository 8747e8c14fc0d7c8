"""A stalled event loop delivers the IMU's backlog after fresher wheel readings: no IMU sample may be lost."""

from __future__ import annotations

import numpy as np
import pytest

from gprbot.fusion.fuser import PoseFuser, SensorMessage
from gprbot.messages import ImuSample, WheelSpeeds
from gprbot.sim.motion_truth import straight_ground_truth
from tests.test_ekf import sensor_messages, start_of


def test_an_imu_backlog_behind_fresher_wheels_is_waited_for_not_dropped() -> None:
    truth = straight_ground_truth(6.0, (0.1, 0.0), seed=2)
    messages = sensor_messages(truth)
    position, yaw = start_of(truth)
    in_order = PoseFuser(initial_position=position, initial_yaw_rad=yaw)
    expected = [p for m in messages for p in in_order.push(m)]
    # From 3 s to 3.5 s the loop stalls: the encoders' readings come on time, the camera's IMU half a second late.
    stalled = [m for m in messages if isinstance(m, ImuSample) and 3.0 <= m.t < 3.5]
    arrival: list[SensorMessage] = []
    for m in messages:
        if isinstance(m, ImuSample) and 3.0 <= m.t < 3.5:
            continue
        if isinstance(m, ImuSample) and m.t >= 3.5 and stalled:
            arrival.extend(stalled)
            stalled = []
        arrival.append(m)
    assert arrival != messages
    fuser = PoseFuser(initial_position=position, initial_yaw_rad=yaw)
    got = [p for m in arrival for p in fuser.push(m)]
    assert fuser.stats.late_dropped == 0 and fuser.stats.imu == in_order.stats.imu
    assert len(got) == len(expected)
    assert np.stack([p.position for p in got]) == pytest.approx(
        np.stack([p.position for p in expected]), abs=1e-12)


def test_a_dead_imu_does_not_freeze_the_poses_for_ever() -> None:
    truth = straight_ground_truth(6.0, (0.1, 0.0), seed=2)
    position, yaw = start_of(truth)
    fuser = PoseFuser(initial_position=position, initial_yaw_rad=yaw)
    messages = [m for m in sensor_messages(truth) if not (isinstance(m, ImuSample) and m.t > 3.0)]
    poses = [p for m in messages for p in fuser.push(m)]
    last_wheel = max(m.t for m in messages if isinstance(m, WheelSpeeds))
    # Beyond the IMU's last sample the wheels still move the poses on, max_imu_wait_s later.
    assert poses[-1].t > 3.0 + 1.0 and poses[-1].t > last_wheel - fuser.config.reorder_window_s - 0.05
