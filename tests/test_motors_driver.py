"""MotorDriver against the RoboClaw emulator over a pty: rates, limits, start-up errors, faults, 100 ms stop."""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import math
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from types import TracebackType

import numpy as np
import pytest

from gprbot.config import MotorsConfig
from gprbot.drivers.motors.driver import MotorDriver
from gprbot.drivers.motors.emulator import RoboClawEmulator
from gprbot.drivers.motors.safety import check_motors_config
from gprbot.errors import ConfigError, DriverError
from gprbot.messages import WheelEncoders, WheelSpeeds, decode, encode
from tests.aio import within

CPR = 1024
CFG = MotorsConfig(
    port="set-per-test",
    encoder_counts_per_rev=CPR,
    command_timeout_s=0.015,  # 3 × 15 ms + a 20 ms control period leaves slack on a loaded test machine
    retries=2,
    failsafe_timeout_s=0.1,
    max_wheel_speed_rad_s=20.0,
    max_wheel_accel_rad_s2=400.0,
)
SPEEDS = np.array([10.0, -5.0, 2.5])
ALL_MOTORS = ((128, 1), (128, 2), (129, 1), (129, 2))
HALF_COUNT = math.pi / CPR  # rad/s: speeds travel as whole counts/s, so they round to within this


def counts_per_s(rad_s: float) -> float:
    """The analytic conversion the driver must apply: rad/s × cpr / 2π."""
    return rad_s * CPR / (2 * math.pi)


def recording_sleep(delays: list[float]) -> Callable[[float], Awaitable[None]]:
    """Backoff sleep that records the requested delays and waits 1/20 of them."""

    async def sleep(delay: float) -> None:
        delays.append(delay)
        await asyncio.sleep(delay / 20)

    return sleep


async def until(predicate: Callable[[], object], timeout: float = 2.0) -> None:
    """Poll `predicate` every 5 ms (real time: the pty link is real)."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        await asyncio.sleep(0.005)


def first_all_stopped(
    emu: RoboClawEmulator, since: float, motors: tuple[tuple[int, int], ...] = ALL_MOTORS
) -> tuple[float, str] | None:
    """(time, source) of the first command event after `since` that leaves every motor targeted at 0."""
    emu.commanded_speed(*motors[0])  # let the emulator evaluate its failsafe up to now
    state = dict.fromkeys(motors, 0.0)
    events = sorted(emu.command_log, key=lambda e: e.t)
    for event in (e for e in events if e.t < since):
        state[(event.address, event.channel)] = event.counts_per_s
    for event in (e for e in events if e.t >= since):
        state[(event.address, event.channel)] = event.counts_per_s
        if not any(state.values()):
            return event.t, event.source
    return None


class Driving:
    """The motion loop at 50 Hz: command speeds, read encoders, record readings and errors."""

    def __init__(self, driver: MotorDriver, speeds: np.ndarray) -> None:
        self.driver = driver
        self.speeds = speeds
        self.readings: list[WheelEncoders] = []
        self.errors: list[tuple[float, DriverError]] = []
        self._task: asyncio.Task[None] | None = None

    async def _run(self) -> None:
        while True:
            try:
                await self.driver.set_wheel_speeds(WheelSpeeds(time.monotonic(), self.speeds))
                self.readings.append(await self.driver.read_encoders())
            except DriverError as exc:
                self.errors.append((time.monotonic(), exc))
            await asyncio.sleep(0.02)

    async def __aenter__(self) -> Driving:
        self._task = asyncio.get_running_loop().create_task(self._run())
        return self

    async def __aexit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        assert self._task is not None
        self._task.cancel()
        await asyncio.gather(self._task, return_exceptions=True)


@pytest.fixture
async def emulator(tmp_path: Path) -> AsyncIterator[tuple[RoboClawEmulator, str]]:
    emu = RoboClawEmulator(addresses=(128, 129), counts_per_rev=CPR)
    path = emu.serve_pty(tmp_path / "usb-Basicmicro_Inc._USB_Roboclaw_2x15A-if00")  # stable, like by-id
    yield emu, path
    emu.close()


@pytest.fixture
async def driver(emulator: tuple[RoboClawEmulator, str]) -> AsyncIterator[MotorDriver]:
    drv = MotorDriver(dataclasses.replace(CFG, port=emulator[1]), sleep=recording_sleep([]))
    await drv.start()
    yield drv
    await drv.close()


# ----- normal operation ------------------------------------------------------------------------------
async def test_start_identifies_arms_failsafe_and_stops(
    driver: MotorDriver, emulator: tuple[RoboClawEmulator, str]
) -> None:
    emu, _ = emulator
    assert driver.firmware == {128: "USB Roboclaw 2x15a v4.1.34", 129: "USB Roboclaw 2x15a v4.1.34"}
    assert emu.serial_timeout_s(128) == emu.serial_timeout_s(129) == 0.1
    assert all(emu.commanded_speed(a, c) == 0.0 for a, c in ALL_MOTORS)
    assert driver.health().connected
    assert await driver.read_battery_voltage(129) == emu.battery_v


async def test_reset_encoders_zeroes_counts(driver: MotorDriver, emulator: tuple[RoboClawEmulator, str]) -> None:
    emu, _ = emulator
    emu.set_encoder_position(128, 2, 12345.0)
    assert (await driver.read_encoders()).counts.tolist() == [0, 12345, 0]
    await driver.reset_encoders()
    assert (await driver.read_encoders()).counts.tolist() == [0, 0, 0]
    assert emu.encoder_position(128, 2) == 0.0


async def test_encoders_advance_at_the_commanded_rate(
    driver: MotorDriver, emulator: tuple[RoboClawEmulator, str]
) -> None:
    emu, _ = emulator
    async with Driving(driver, SPEEDS) as loop:
        await until(lambda: len(loop.readings) >= 30)
    assert not loop.errors
    settled = [r for r in loop.readings if r.t > loop.readings[0].t + 0.2]  # ramp 25 ms, lag tau 50 ms
    first, last = settled[0], settled[-1]
    rate = (last.counts - first.counts) / (last.t - first.t)
    np.testing.assert_allclose(rate, [counts_per_s(w) for w in SPEEDS], rtol=0.03)
    np.testing.assert_allclose(last.speeds, SPEEDS, rtol=0.01)  # speeds come back in rad/s
    # wheel i drives (address, channel) = wheel_map[i]; channel 2 of 129 is not a wheel
    np.testing.assert_allclose([emu.commanded_speed(a, c) for a, c in CFG.wheel_map], SPEEDS, atol=HALF_COUNT)
    assert emu.commanded_speed(129, 2) == 0.0
    assert driver.health().rate_hz > 20
    assert decode(encode(last)).counts.tolist() == last.counts.tolist()  # a registered message
    assert last.wheel_speeds().speeds.tolist() == last.speeds.tolist()


async def test_speeds_are_clamped(driver: MotorDriver, emulator: tuple[RoboClawEmulator, str]) -> None:
    emu, _ = emulator
    await driver.set_wheel_speeds(WheelSpeeds(0.0, np.array([100.0, -100.0, 0.0])))
    assert emu.commanded_speed(128, 1) == pytest.approx(20.0, abs=HALF_COUNT)
    assert emu.commanded_speed(128, 2) == pytest.approx(-20.0, abs=HALF_COUNT)
    with pytest.raises(ValueError, match="non-finite"):
        await driver.set_wheel_speeds(WheelSpeeds(0.0, np.array([np.nan, 1.0, 1.0])))
    assert emu.commanded_speed(128, 1) == 0.0


async def test_counts_unwrap_across_the_32_bit_wrap(
    driver: MotorDriver, emulator: tuple[RoboClawEmulator, str]
) -> None:
    emu, _ = emulator
    emu.set_encoder_position(128, 1, 2**32 - 300)  # the controller's counter is about to wrap
    async with Driving(driver, np.array([10.0, 0.0, 0.0])) as loop:
        await until(lambda: loop.readings and loop.readings[-1].counts[0] > 200)
    counts = [int(r.counts[0]) for r in loop.readings]
    assert counts[0] < 0  # 2³² - 300 read as -300
    assert all(0 <= b - a < 200 for a, b in itertools.pairwise(counts))


async def test_controller_stops_itself_when_the_host_goes_quiet(
    driver: MotorDriver, emulator: tuple[RoboClawEmulator, str]
) -> None:
    emu, _ = emulator
    await driver.set_wheel_speeds(WheelSpeeds(0.0, SPEEDS))
    quiet_since = time.monotonic()
    await asyncio.sleep(0.15)
    stopped = first_all_stopped(emu, quiet_since)
    assert stopped is not None and stopped[1] == "failsafe"
    assert stopped[0] - quiet_since <= 0.1
    assert all(emu.commanded_speed(a, c) == 0.0 for a, c in ALL_MOTORS)
    assert emu.motor_speed(128, 1) < 0.5 * SPEEDS[0]  # and the wheel is slowing down (tau 50 ms)


async def test_stop_goes_ahead_of_queued_requests(
    driver: MotorDriver, emulator: tuple[RoboClawEmulator, str]
) -> None:
    emu, _ = emulator
    before = emu.packets_handled
    reads = [asyncio.get_running_loop().create_task(driver.read_encoders()) for _ in range(5)]
    await asyncio.sleep(0)  # one request on the line, four queued behind it
    try:
        await driver.stop()
        # the one in flight + two stop packets (FIFO would put the four queued reads first)
        assert emu.packets_handled - before <= 4
    finally:
        await asyncio.gather(*reads)


async def test_stop_is_not_undone_by_a_command_it_overtook(
    driver: MotorDriver, emulator: tuple[RoboClawEmulator, str]
) -> None:
    emu, _ = emulator
    command = asyncio.get_running_loop().create_task(driver.set_wheel_speeds(WheelSpeeds(0.0, SPEEDS)))
    await asyncio.sleep(0)  # the packet for controller 128 is on the line; 129's is still to come
    await driver.stop()
    await command
    assert all(emu.commanded_speed(a, c) == 0.0 for a, c in ALL_MOTORS)


# ----- start-up errors and configuration ----------------------------------------------------------------
async def test_silent_address_names_port_and_address(tmp_path: Path) -> None:
    emu = RoboClawEmulator(addresses=(128,), counts_per_rev=CPR)
    path = emu.serve_pty(tmp_path / "roboclaw")
    try:
        with pytest.raises(DriverError, match=r"no RoboClaw answers at address 129 \(0x81\) on .*roboclaw"):
            await MotorDriver(dataclasses.replace(CFG, port=path)).start()
    finally:
        emu.close()


@pytest.mark.parametrize(
    ("firmware", "noisy", "message"),
    [("Sabertooth 2x32 v1.0", False, "identifies as 'Sabertooth"), (None, True, "corrupt replies")],
)
async def test_wrong_device_is_refused(tmp_path: Path, firmware: str | None, noisy: bool, message: str) -> None:
    emu = RoboClawEmulator(counts_per_rev=CPR, **({"firmware": firmware} if firmware else {}))
    if noisy:
        emu.corrupt_replies()
    path = emu.serve_pty(tmp_path / "roboclaw")
    try:
        with pytest.raises(DriverError, match=message):
            await MotorDriver(dataclasses.replace(CFG, port=path)).start()
    finally:
        emu.close()


async def test_two_addresses_on_one_usb_controller_are_refused(tmp_path: Path) -> None:
    emu = RoboClawEmulator(addresses=(128,), counts_per_rev=CPR, usb=True)  # answers 129 as well
    path = emu.serve_pty(tmp_path / "roboclaw")
    try:
        with pytest.raises(DriverError, match=r"reach the same controller"):
            await MotorDriver(dataclasses.replace(CFG, port=path)).start()
    finally:
        emu.close()


async def test_missing_port_and_sim_port(tmp_path: Path) -> None:
    with pytest.raises(DriverError, match="cannot open serial port"):
        await MotorDriver(dataclasses.replace(CFG, port=str(tmp_path / "absent"))).start()
    with pytest.raises(DriverError, match="serve_pty"):
        await MotorDriver(dataclasses.replace(CFG, port="sim")).start()


@pytest.mark.parametrize(
    ("change", "key"),
    [
        ({"failsafe_timeout_s": 0.2}, "motors.failsafe_timeout_s"),
        ({"failsafe_timeout_s": 0.0}, "motors.failsafe_timeout_s"),
        ({"command_timeout_s": 0.05}, "motors.command_timeout_s"),
        ({"wheel_map": ((128, 1), (128, 1), (129, 1))}, "motors.wheel_map"),
        ({"wheel_map": ((128, 3),)}, "motors.wheel_map"),
    ],
)
def test_unsafe_or_inconsistent_config_is_refused(change: dict[str, object], key: str) -> None:
    with pytest.raises(ConfigError, match=key):
        check_motors_config(dataclasses.replace(CFG, **change))  # type: ignore[arg-type]


# ----- faults: reported, wheels stopped within 100 ms, recovery -------------------------------------------
FAULTS: dict[str, tuple[Callable[[RoboClawEmulator], object], Callable[[RoboClawEmulator], object], str]] = {
    # name: (inject, recover, what stops the wheels)
    "unplugged": (RoboClawEmulator.unplug, RoboClawEmulator.replug, "failsafe"),
    "stalled": (RoboClawEmulator.stall, RoboClawEmulator.clear_faults, "failsafe"),
    "silent": (lambda e: e.drop_replies(), RoboClawEmulator.clear_faults, "serial"),
    "bad_crc": (lambda e: e.corrupt_replies(), RoboClawEmulator.clear_faults, "serial"),
    "noise": (lambda e: e.noisy_replies(), RoboClawEmulator.clear_faults, "serial"),
}


@pytest.mark.parametrize("fault", FAULTS)
async def test_fault_is_reported_stopped_within_100_ms_and_recovers(
    emulator: tuple[RoboClawEmulator, str], fault: str
) -> None:
    emu, path = emulator
    inject, recover, stopper = FAULTS[fault]
    delays: list[float] = []
    drv = MotorDriver(dataclasses.replace(CFG, port=path), sleep=recording_sleep(delays))
    await drv.start()
    try:
        async with Driving(drv, SPEEDS) as loop:
            await until(lambda: len(loop.readings) >= 5 and emu.commanded_speed(128, 1) > 9)
            t_fault = time.monotonic()
            inject(emu)
            await until(lambda: loop.errors)  # the caller gets a DriverError
            health = drv.health()
            assert not health.connected and health.last_error and health.errors >= 1
            await until(lambda: first_all_stopped(emu, t_fault) is not None, timeout=0.5)
            stopped = first_all_stopped(emu, t_fault)
            assert stopped is not None
            assert stopped[0] - t_fault <= 0.1, f"wheels stopped {stopped[0] - t_fault:.3f} s after the fault"
            assert stopped[1] == stopper
            assert all(emu.commanded_speed(a, c) == 0.0 for a, c in ALL_MOTORS)  # the model obeyed the log
            recover(emu)
            await within(drv.wait_connected(), 3.0)
            seen = len(loop.readings)
            await until(lambda: len(loop.readings) > seen + 3 and emu.commanded_speed(128, 1) > 9)
        assert drv.health().connected and drv.reconnects == 1
        assert delays[0] == 0.1
    finally:
        await drv.close()


async def test_transient_corruption_is_retried_without_a_fault(
    driver: MotorDriver, emulator: tuple[RoboClawEmulator, str]
) -> None:
    emu, _ = emulator
    async with Driving(driver, SPEEDS) as loop:
        await until(lambda: len(loop.readings) >= 3)
        errors = driver.health().errors
        emu.corrupt_replies(1)
        emu.inject_noise(16)
        await until(lambda: len(loop.readings) >= 8)
    assert not loop.errors and driver.health().connected
    assert driver.health().errors >= errors + 1


async def test_reconnect_backoff_doubles_up_to_the_cap(emulator: tuple[RoboClawEmulator, str]) -> None:
    emu, path = emulator
    delays: list[float] = []
    drv = MotorDriver(dataclasses.replace(CFG, port=path), sleep=recording_sleep(delays))
    await drv.start()
    try:
        emu.unplug()
        with pytest.raises(DriverError, match="fault"):
            await drv.read_encoders()
        await until(lambda: len(delays) >= 7)
        assert delays[:7] == [0.1, 0.2, 0.4, 0.8, 1.6, 2.0, 2.0]
        emu.replug()
        await within(drv.wait_connected(), 3.0)
    finally:
        await drv.close()


async def test_controllers_on_separate_usb_ports(tmp_path: Path) -> None:
    emu_a, emu_b = RoboClawEmulator(addresses=(128,)), RoboClawEmulator(addresses=(129,))
    port_a, port_b = emu_a.serve_pty(tmp_path / "roboclaw-a"), emu_b.serve_pty(tmp_path / "roboclaw-b")
    drv = MotorDriver(dataclasses.replace(CFG, port=port_a), ports={129: port_b}, sleep=recording_sleep([]))
    await drv.start()
    try:
        async with Driving(drv, SPEEDS) as loop:
            await until(lambda: len(loop.readings) >= 5)
            assert emu_a.commanded_speed(128, 2) == pytest.approx(-5.0, abs=HALF_COUNT)
            assert emu_b.commanded_speed(129, 1) == pytest.approx(2.5, abs=HALF_COUNT)
            t_fault = time.monotonic()
            emu_b.unplug()
            await until(lambda: loop.errors)
            await asyncio.sleep(0.12)
            stopped_a = first_all_stopped(emu_a, t_fault, ((128, 1), (128, 2)))
            stopped_b = first_all_stopped(emu_b, t_fault, ((129, 1), (129, 2)))
            assert stopped_a is not None and stopped_a[1] == "serial"  # the driver stops the healthy one
            assert stopped_b is not None and stopped_b[1] == "failsafe"  # the unplugged one stops itself
            assert max(stopped_a[0], stopped_b[0]) - t_fault <= 0.1
            emu_b.replug()
            await within(drv.wait_connected(), 3.0)
    finally:
        await drv.close()
        emu_a.close()
        emu_b.close()
