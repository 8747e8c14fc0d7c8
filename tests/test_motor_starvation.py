"""The motor link on a starved event loop: a busy loop is not a silent controller (issues 14/15).

The loop is blocked right after a request is written — the worst place: the reply (or, with the
emulator on the same loop, the emulator's own turn) then sits behind the block, and the reply
timeout fires in the same pass as the reply's reader. Before the fix every attempt timed out there,
the driver declared a fault and stopped the wheels mid-line.
"""

from __future__ import annotations

import asyncio
import dataclasses
import os
import select
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import numpy as np
import pytest

from gprbot.config import MotorsConfig
from gprbot.drivers.motors.bus import PriorityLock
from gprbot.drivers.motors.driver import MotorDriver
from gprbot.drivers.motors.emulator import RoboClawEmulator
from gprbot.drivers.motors.pty_link import PtyLink
from gprbot.errors import DriverError
from gprbot.messages import WheelSpeeds
from tests.aio import within

CFG = MotorsConfig(port="set-per-test", command_timeout_s=0.02, retries=2)
BLOCK_S = 0.05  # longer than the 20 ms reply timeout, shorter than the controllers' 100 ms failsafe


def block_after_writes(driver: MotorDriver, block_s: float, every: int = 1) -> list[float]:
    """Make the loop hold still for `block_s` right after every `every`-th packet the driver writes."""
    written: list[float] = []
    for bus in driver._buses.values():
        port = bus.port
        write = port.write

        def blocked_write(data: bytes, write: Callable[[bytes], None] = write) -> None:
            write(data)
            written.append(time.monotonic())
            if len(written) % every == 0:
                asyncio.get_running_loop().call_soon(time.sleep, block_s)  # runs in this very loop pass

        port.write = blocked_write  # type: ignore[method-assign]
    return written


@pytest.fixture
async def on_loop(tmp_path: Path) -> AsyncIterator[tuple[RoboClawEmulator, MotorDriver]]:
    """An emulator served on the daemon's own loop (the worst case) and a started driver."""
    emu = RoboClawEmulator(addresses=(128, 129))
    path = emu.serve_pty(tmp_path / "roboclaw")
    driver = MotorDriver(dataclasses.replace(CFG, port=path))
    await driver.start()
    yield emu, driver
    await driver.close()
    emu.close()


@pytest.mark.parametrize("block_s", [0.021, BLOCK_S])  # just past the 20 ms deadline, and far past it
async def test_a_busy_loop_after_every_request_is_not_a_link_fault(
    on_loop: tuple[RoboClawEmulator, MotorDriver], block_s: float,
) -> None:
    emu, driver = on_loop
    block_after_writes(driver, block_s)
    for _ in range(5):
        await driver.set_wheel_speeds(WheelSpeeds(time.monotonic(), [3.0, -1.5, -1.5]))
        await driver.read_encoders()
    assert driver.connected and driver.reconnects == 0
    assert driver.health().errors == 0, driver.health().last_error
    assert emu.commanded_speed(128, 1) > 2.9  # the commands got through, not the fault path's stops


async def test_encoder_readings_are_stamped_when_the_speed_requests_left(
    on_loop: tuple[RoboClawEmulator, MotorDriver],
) -> None:
    _, driver = on_loop
    quiet = await driver.read_encoders()
    assert quiet.speed_spread_s < 0.02
    written = block_after_writes(driver, BLOCK_S, every=2)  # the loop stalls after every second request
    began = time.monotonic()
    reading = await driver.read_encoders()
    took = time.monotonic() - began
    assert took > 3 * BLOCK_S  # three stalls of 50 ms are inside this read
    assert len(written) == 6  # speeds of the three wheels first, then their counts
    speeds_sent = written[:3]
    assert abs(reading.t - max(speeds_sent)) < 0.005  # the requests' times, not the replies'
    # A stall between two speed requests: the three speeds are not one instant, and the reading says
    # when each was sampled
    assert reading.speed_spread_s == pytest.approx(max(speeds_sent) - min(speeds_sent), abs=1e-3)
    assert reading.speed_spread_s >= BLOCK_S
    assert reading.speed_offsets_s is not None
    assert reading.speed_offsets_s == pytest.approx(np.array(speeds_sent) - max(speeds_sent), abs=5e-3)


async def test_a_silent_controller_is_still_a_fault_within_100_ms(
    on_loop: tuple[RoboClawEmulator, MotorDriver],
) -> None:
    emu, driver = on_loop
    emu.drop_replies()
    began = time.monotonic()
    with pytest.raises(DriverError, match="motor fault"):
        await driver.read_encoders()
    assert time.monotonic() - began < 0.1  # (1 + retries) × (20 + 5 ms grace) = 75 ms: within the stop bound
    assert not driver.connected


async def test_a_cancelled_waiter_already_dropped_by_release_is_not_an_error() -> None:
    lock = PriorityLock()
    await lock.acquire()
    waiter = asyncio.ensure_future(lock.acquire())
    await asyncio.sleep(0)
    waiter.cancel()  # cancelled, but its CancelledError is not delivered yet...
    lock.release()  # ...when release() skips the cancelled future and drops it from the queue
    with pytest.raises(asyncio.CancelledError):
        await waiter  # used to raise ValueError from deque.remove
    await within(lock.acquire(), 0.1)  # and the lock is free, not leaked


async def test_a_threaded_link_answers_while_the_loop_is_blocked() -> None:
    link = PtyLink(lambda data: data.upper(), threaded=True)
    path = link.open()
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(fd, b"ping")
        time.sleep(BLOCK_S)  # the loop is blocked here; a loop-served link could not answer
        readable, _, _ = select.select([fd], [], [], 0)
        assert readable and os.read(fd, 16) == b"PING"
    finally:
        os.close(fd)
        link.close()
    assert not link.is_open


async def test_the_emulator_in_its_thread_serves_the_driver(tmp_path: Path) -> None:
    emu = RoboClawEmulator(addresses=(128, 129))
    driver = MotorDriver(dataclasses.replace(CFG, port=emu.serve_pty(tmp_path / "rc", threaded=True)))
    await driver.start()
    try:
        await driver.set_wheel_speeds(WheelSpeeds(time.monotonic(), [2.0, 0.0, 0.0]))
        await asyncio.sleep(0.1)
        assert (await driver.read_encoders()).counts[0] > 0
        assert emu.command_log and emu.serial_timeout_s(128) == 0.1
    finally:
        await driver.close()
        emu.close()

