"""DeviceClock: device milliseconds → host monotonic seconds, against injected sequences with known truth."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gprbot.drivers.realsense.clock import DeviceClock

OFFSET_S = 1234.5  # host monotonic time at device time 0


def feed(clock: DeviceClock, device_s: np.ndarray, latency_s: np.ndarray, stream: str = "") -> np.ndarray:
    """Convert samples taken at host time device_s + OFFSET_S and received latency_s later."""
    return np.array([
        clock.to_host(d * 1000.0, d + OFFSET_S + lat, stream) for d, lat in zip(device_s, latency_s, strict=True)
    ])


def test_live_offset_converges_to_the_minimum_delay() -> None:
    rng = np.random.default_rng(0)
    device_s = np.arange(2000) / 400.0
    latency_s = 0.002 + rng.exponential(0.003, device_s.size)
    latency_s[100] = 0.0005  # the least-delayed sample fixes the offset from here on
    host = feed(DeviceClock(), device_s, latency_s)
    error = host - (device_s + OFFSET_S)
    assert np.all(error[100:] == pytest.approx(0.0005, abs=1e-9))
    assert np.all((error[:100] >= 0.0005 - 1e-12) & (error[:100] <= latency_s[0] + 1e-12))


def test_late_samples_do_not_move_the_estimate_and_are_no_jump() -> None:
    device_s = np.arange(400) / 400.0
    latency_s = np.full(device_s.size, 0.001)
    latency_s[200:220] = 0.35  # the host stalled; samples queue up in the SDK
    clock = DeviceClock(jump_threshold_s=0.1)
    host = feed(clock, device_s, latency_s)
    assert clock.jumps == []
    assert np.allclose(host, device_s + OFFSET_S + 0.001, atol=1e-9)


def test_forward_leap_of_the_device_clock_is_one_jump_and_reanchors() -> None:
    device_s = np.arange(800) / 400.0
    device_s[400:] += 5.0  # the device clock leaps 5 s ahead; real time goes on 2.5 ms per sample
    real_s = np.arange(800) / 400.0
    clock = DeviceClock()
    host = [clock.to_host(d * 1000.0, r + OFFSET_S + 0.001) for d, r in zip(device_s, real_s, strict=True)]
    assert len(clock.jumps) == 1
    assert clock.jumps[0].device_s == pytest.approx(device_s[400])
    assert clock.jumps[0].offset_change_s == pytest.approx(-5.0)
    assert np.allclose(host, real_s + OFFSET_S + 0.001, atol=1e-9)


def test_device_reset_is_counted_once_across_streams() -> None:
    clock = DeviceClock()
    real = np.arange(0, 2.0, 0.0025)
    events = []  # (real time, device time, stream): gyro every 2.5 ms, accel every 4 ms
    events += [(r, r + 100.0 if r < 1.0 else r - 1.0, "gyro") for r in real]
    events += [(r, r + 100.0 if r < 1.0 else r - 1.0, "accel") for r in np.arange(0, 2.0, 0.004)]
    events.sort()
    host = [clock.to_host(d * 1000.0, r + OFFSET_S + 0.001, s) for r, d, s in events]
    assert len(clock.jumps) == 1  # the device restarted its clock at real time 1 s
    assert np.allclose(host, [r + OFFSET_S + 0.001 for r, _, _ in events], atol=1e-9)


def test_late_video_interleaved_with_imu_shares_the_imu_offset() -> None:
    clock = DeviceClock()
    imu = [(d, d + 0.001, "gyro") for d in np.arange(0, 3.0, 0.0025)]
    video = [(d, d + 0.060, "rgbd") for d in np.arange(0, 3.0, 1 / 30)]  # 60 ms of exposure + USB transfer
    events = sorted(imu + video, key=lambda e: e[1])  # in order of arrival
    host = {(s, d): clock.to_host(d * 1000.0, r + OFFSET_S, s) for d, r, s in events}
    assert clock.jumps == []
    for (_, d), t in host.items():
        if d > 0.01:  # once the first IMU sample has arrived
            assert t == pytest.approx(d + OFFSET_S + 0.001, abs=1e-9)


@pytest.mark.parametrize("ppm", [-80.0, 80.0])
def test_live_conversion_follows_crystal_drift(ppm: float) -> None:
    real = np.arange(0, 60.0, 0.0025)
    device_s = real * (1 + ppm * 1e-6)
    host = feed(DeviceClock(window_s=2.0), device_s, real - device_s + 0.001)
    error = host - (real + OFFSET_S)
    assert np.max(np.abs(error)) < 0.001 + 0.0002  # the latency, plus at most 2 s of drift at 80 ppm


def test_playback_keeps_the_recorded_spacing_whatever_the_receive_times() -> None:
    device_s = 17.0 + np.arange(400) / 400.0
    receive = 3.0 + np.cumsum(np.random.default_rng(1).uniform(0.0, 0.0003, device_s.size))  # ~8x real time
    clock = DeviceClock(follow_host=False)
    host = np.array([clock.to_host(d * 1000.0, r) for d, r in zip(device_s, receive, strict=True)])
    assert clock.jumps == []
    assert np.allclose(host - host[0], device_s - device_s[0], atol=1e-9)
    assert host[0] == pytest.approx(receive[0])


def test_playback_reset_continues_after_the_last_output() -> None:
    clock = DeviceClock(follow_host=False)
    first = [clock.to_host(1000.0 + 10.0 * i, 0.001 * i) for i in range(10)]
    after = [clock.to_host(10.0 * i, 0.02 + 0.001 * i) for i in range(10)]  # the recording's clock restarts
    assert len(clock.jumps) == 1
    assert after[0] >= first[-1]
    assert np.allclose(np.diff(after), 0.010)


def test_reset_forgets_the_offset_without_counting_a_jump() -> None:
    clock = DeviceClock()
    clock.to_host(500_000.0, 10.0)
    clock.reset()
    assert clock.offset_s is None
    assert clock.to_host(0.0, 11.0) == 11.0
    assert clock.jumps == []


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0.0, 0.05), min_size=2, max_size=200))
def test_live_error_never_exceeds_the_least_latency_seen(latencies: list[float]) -> None:
    device_s = np.arange(len(latencies)) / 400.0
    latency = np.array(latencies)
    host = feed(DeviceClock(jump_threshold_s=0.1), device_s, latency)
    error = host - (device_s + OFFSET_S)
    assert np.all(error >= -1e-9)
    assert np.all(error <= np.minimum.accumulate(latency) + 1e-9)
