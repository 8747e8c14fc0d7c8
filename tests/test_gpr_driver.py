"""The GPR driver against the SDK-mode emulator on loopback sockets: bring-up, traces, faults, recovery."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import itertools
import socket
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

import numpy as np
import pytest

from gprbot.config import GprDeviceConfig
from gprbot.drivers.gpr.driver import GprDriver, NicClock
from gprbot.drivers.gpr.emulator import GprSdkEmulator
from gprbot.drivers.gpr.protocol import DeviceRejectedError, TraceFrame, TraceStreamParser
from gprbot.drivers.gpr.raw_replay import traces_from_raw
from gprbot.errors import DriverError
from gprbot.messages import GprRawChunk, GprStreamSetup, Trace

PPT = 128
RATE_HZ = 250.0
BASE = GprDeviceConfig(points_per_trace=PPT, time_sampling_interval_ps=100.0, stacks=4, window_shift_ns=-1.0,
                       trigger_period_s=0.004, connect_timeout_s=1.0)


def source(n: int) -> np.ndarray:
    """A synthetic trace, different for every number."""
    return (np.sin(np.arange(PPT, dtype=np.float64) * 0.1 + n) * (1 + n % 7)).astype(np.float32)


class RecordingSleep:
    """An injected backoff sleep: records the delays asked for, waits only a few ms."""

    def __init__(self) -> None:
        self.delays: list[float] = []

    async def __call__(self, delay: float) -> None:
        self.delays.append(delay)
        await asyncio.sleep(0.005)


@pytest.fixture
async def emulator() -> AsyncIterator[GprSdkEmulator]:
    emu = GprSdkEmulator(source, rate_hz=RATE_HZ)
    await emu.start()
    yield emu
    await emu.stop()


@contextlib.asynccontextmanager
async def running(emu: GprSdkEmulator, **kwargs: Any) -> AsyncIterator[GprDriver]:
    """A started driver on the emulator, stopped on exit."""
    driver = GprDriver(emu.driver_config(BASE), **kwargs)
    await driver.start()
    try:
        yield driver
    finally:
        await driver.close()


Action = Callable[[], Awaitable[None] | None]


async def take(driver: GprDriver, count: int, actions: dict[int, Action] | None = None) -> list[Trace]:
    """Collect `count` traces, running actions[k] after the k-th one."""
    got: list[Trace] = []
    async with asyncio.timeout(8.0), contextlib.aclosing(driver.traces()) as stream:
        async for trace in stream:
            got.append(trace)
            action = (actions or {}).get(len(got))
            if action is not None:
                result = action()
                if result is not None:
                    await result
            if len(got) >= count:
                break
    return got


async def until(predicate: Callable[[], bool], timeout_s: float = 5.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not predicate():
            await asyncio.sleep(0.01)


def assert_exact_and_increasing(traces: list[Trace], offset: int = 0) -> None:
    numbers = [t.number for t in traces]
    assert numbers == sorted(set(numbers)), numbers
    for t in traces:
        assert np.array_equal(t.samples, source(t.number - offset)), t.number


# ---- bring-up -----------------------------------------------------------------------------------


async def test_start_receives_traces_in_order_with_exact_samples(emulator: GprSdkEmulator) -> None:
    def host_clock() -> float:  # a host clock unlike the NIC's
        return time.monotonic() + 1000.0

    raw: list[GprStreamSetup | GprRawChunk] = []
    async with running(emulator, clock=host_clock, raw_sink=raw.append) as driver:
        got = await take(driver, 25)
        health = driver.health()
    assert [t.number for t in got] == list(range(1, 26))
    assert_exact_and_increasing(got)
    first = got[0]
    assert (first.dt_ns, first.t0_ns, first.stacks) == (0.1, 1.0, 4) and first.samples.dtype == np.float32
    assert all(abs(t.t - time.monotonic() - 1000.0) < 1.0 for t in got)  # host time, not the NIC's 1970-based clock
    assert all(b.t >= a.t for a, b in itertools.pairwise(got))
    assert health.connected and health.drops == 0 and health.errors == 0 and health.rate_hz > 50
    setup_put = ("PUT", "/api/nic/setup")
    order = [r for r in emulator.requests if r in (("GET", "/api"), ("PUT", "/api/nic/power"), setup_put,
                                                  ("PUT", "/api/nic/acquisition"))]
    assert order[:4] == [("GET", "/api"), ("PUT", "/api/nic/power"), setup_put, ("PUT", "/api/nic/acquisition")]
    assert emulator.acquisition_state == 0  # stop() stopped the acquisition
    chunks = b"".join(r.data for r in raw if isinstance(r, GprRawChunk))
    replayed = [e for e in TraceStreamParser(PPT).feed(chunks) if isinstance(e, TraceFrame)]
    assert [(e.number, e.samples.tobytes()) for e in replayed[:25]] == [(t.number, t.samples.tobytes()) for t in got]
    again = traces_from_raw(raw)  # the recorded stream through the driver's parser and clock: the same traces
    assert [(t.t, t.number, t.dt_ns, t.t0_ns, t.samples.tobytes()) for t in again[:25]] == [
        (t.t, t.number, t.dt_ns, t.t0_ns, t.samples.tobytes()) for t in got]


async def test_stop_ends_the_trace_iterator(emulator: GprSdkEmulator) -> None:
    driver = GprDriver(emulator.driver_config(BASE))
    await driver.start()
    await take(driver, 3)
    await driver.close()
    async with asyncio.timeout(2.0):
        remaining = [t async for t in driver.traces()]
    assert all(t.number > 3 for t in remaining)


async def test_absent_device_is_a_clear_error() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # bound, not listening: nothing answers
        cfg = GprDeviceConfig(host="127.0.0.1", http_port=port, connect_timeout_s=0.5)
        with pytest.raises(DriverError, match=r"no GPR answers at http://127\.0\.0\.1"):
            await GprDriver(cfg).start()


async def test_sim_host_is_refused_with_a_hint() -> None:
    with pytest.raises(DriverError, match="GprSdkEmulator"):
        await GprDriver(GprDeviceConfig()).start()


async def test_another_api_answering_is_named() -> None:
    async with GprSdkEmulator(source, identity="NIC-500 OEM") as emu:
        with pytest.raises(DriverError, match=r"answers as 'NIC-500 OEM', not 'NIC-500 SDK'"):
            await GprDriver(emu.driver_config(BASE)).start()
        assert ("PUT", "/api/nic/power") not in emu.requests


@pytest.mark.parametrize(
    "answer",
    [b"SSH-2.0-OpenSSH_9.6\r\n",
     b"HTTP/1.1 200 OK\r\nContent-Type: text/html\r\nContent-Length: 13\r\n\r\n<html></html>"],
)
async def test_something_else_answering_is_a_clear_error(answer: bytes) -> None:
    async def impostor(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.write(answer)
        await writer.drain()
        writer.close()

    server = await asyncio.start_server(impostor, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    try:
        with pytest.raises(DriverError, match="not a NIC-500 in SDK mode"):
            await GprDriver(GprDeviceConfig(host="127.0.0.1", http_port=port, connect_timeout_s=1.0)).start()
    finally:
        server.close()
        await server.wait_closed()


async def test_rejected_setup_is_a_clear_error(emulator: GprSdkEmulator) -> None:
    emulator.reject_setup(status_code=8, http_status=400)
    with pytest.raises(DriverError, match=r"rejected the acquisition setup \(status 8") as err:
        await GprDriver(emulator.driver_config(BASE)).start()
    assert isinstance(err.value.__cause__, DeviceRejectedError)
    assert emulator.acquisition_state == 0
    await until(lambda: emulator._client is None)  # the data socket was closed again


async def test_out_of_range_setup_names_the_config_keys(emulator: GprSdkEmulator) -> None:
    cfg = emulator.driver_config(BASE)
    bad = GprDriver(dataclasses.replace(cfg, time_sampling_interval_ps=23.4375))
    with pytest.raises(DriverError, match="time_sampling_interval_ps"):
        await bad.start()


async def test_rounded_setup_is_applied_and_reported(emulator: GprSdkEmulator) -> None:
    cfg = dataclasses.replace(emulator.driver_config(BASE), time_sampling_interval_ps=120.0)
    driver = GprDriver(cfg)
    await driver.start()
    try:
        [trace] = await take(driver, 1)
    finally:
        await driver.close()
    assert trace.dt_ns == pytest.approx(0.1)  # the NIC rounds to its 50 ps steps; the driver uses that
    assert "adjusted the setup: time_sampling_interval_ps 120.0 -> 100.0" in (driver.health().last_error or "")


# ---- faults -------------------------------------------------------------------------------------


async def test_unplug_reconnects_and_continues_without_loss_or_duplicates(emulator: GprSdkEmulator) -> None:
    sleep = RecordingSleep()
    async with running(emulator, sleep=sleep) as driver:
        got = await take(driver, 45, {10: emulator.unplug, 25: emulator.unplug})
        stats = driver.stats()
        health = driver.health()
    assert_exact_and_increasing(got)
    assert stats.reconnects == 2 and sleep.delays == [0.1, 0.1]
    assert stats.resyncs == 0 and stats.duplicates == 0
    missing = got[-1].number - len(got)  # numbers start at 1
    assert missing > 0 and stats.drops == missing and health.drops == missing


async def test_cable_out_backs_off_exponentially_then_recovers(emulator: GprSdkEmulator) -> None:
    sleep = RecordingSleep()
    async with running(emulator, sleep=sleep, backoff_max_s=0.8) as driver:
        before = await take(driver, 5)
        await emulator.go_offline()
        await until(lambda: len(sleep.delays) >= 6)
        offline = driver.health()
        await emulator.come_online()
        after = await take(driver, 10)
    assert sleep.delays[:6] == [0.1, 0.2, 0.4, 0.8, 0.8, 0.8]
    assert not offline.connected and "reconnect failed: no GPR answers" in (offline.last_error or "")
    assert_exact_and_increasing(before + after)


async def test_noise_is_resynchronised_and_later_traces_are_exact(emulator: GprSdkEmulator) -> None:
    async with running(emulator) as driver:
        got = await take(driver, 40, {
            8: lambda: emulator.inject_noise(57, seed=1),
            20: lambda: emulator.inject_noise(13, inside_frame=True, seed=2),
        })
        stats = driver.stats()
        health = driver.health()
    assert_exact_and_increasing(got)
    assert stats.resyncs == 2 and stats.bytes_skipped > 57 + 13
    assert health.errors >= 2 and stats.drops == got[-1].number - len(got) >= 2


async def test_stall_is_reported_then_the_stream_resumes(emulator: GprSdkEmulator) -> None:
    async with running(emulator, stall_timeout_s=0.25, sleep=RecordingSleep()) as driver:
        before = await take(driver, 5, {5: emulator.stall})
        await until(lambda: driver.stats().stalls >= 1)
        health = driver.health()
        await until(lambda: driver.stats().reconnects >= 1)  # traces sent while reconnecting would be lost
        emulator.resume()
        after = await take(driver, 10)
    assert health.last_error is not None and "stalled" in health.last_error
    assert_exact_and_increasing(before + after)
    assert driver.stats().drops == 0  # a stalled NIC produces nothing, so nothing is missing


async def test_skipped_numbers_are_counted_as_drops(emulator: GprSdkEmulator) -> None:
    async with running(emulator) as driver:
        got = await take(driver, 15, {5: lambda: emulator.skip_numbers(7)})
        health = driver.health()
    assert_exact_and_increasing(got)
    numbers = [t.number for t in got]
    assert health.drops == 7 and numbers[-1] - numbers[0] + 1 - len(numbers) == 7


async def test_power_cycle_reruns_setup_and_numbers_keep_increasing(emulator: GprSdkEmulator) -> None:
    async with running(emulator, sleep=RecordingSleep()) as driver:
        got = await take(driver, 30, {10: emulator.power_cycle})
    assert sum(1 for r in emulator.requests if r == ("PUT", "/api/nic/setup")) == 2
    numbers = [t.number for t in got]
    assert numbers == sorted(set(numbers))
    restart = next(i for i, t in enumerate(got) if not np.array_equal(t.samples, source(t.number)))
    base = got[restart - 1].number  # the NIC counts from 1 again; the driver continues from here
    assert_exact_and_increasing(got[:restart])
    assert_exact_and_increasing(got[restart:], offset=base)


async def test_device_clock_jump_is_reported_and_host_times_stay_sane() -> None:
    shift = [0.0]
    emu = GprSdkEmulator(source, rate_hz=RATE_HZ, device_clock=lambda: time.time() + shift[0])
    async with emu, running(emu) as driver:
        got = await take(driver, 20, {8: lambda: shift.__setitem__(0, -3600.0)})
        stats = driver.stats()
    assert stats.clock_jumps == 1
    assert all(abs(t.t - time.monotonic()) < 5.0 for t in got)


# ---- the device clock (pure) --------------------------------------------------------------------


def test_device_clock_keeps_the_least_latency_offset_and_detects_jumps() -> None:
    rng = np.random.default_rng(3)
    clock = NicClock(max_latency_s=2.0)
    device = 1.7e9 + np.arange(300) * 0.01
    latency = rng.uniform(0.0, 0.005, 300)
    latency[0] = 0.2  # the first trace arrived late: the estimate must improve from it
    host = 500.0 + device - 1.7e9 + latency
    t = np.array([clock.to_host(d, h) for d, h in zip(device, host, strict=True)])
    truth = host - latency
    assert clock.jumps == 0
    assert np.all(np.abs(t[20:] - truth[20:]) < 0.002) and np.all(np.diff(t) >= 0)
    # The NIC's clock is set back by an hour: re-anchored, counted, times continue.
    t_jump = clock.to_host(device[-1] - 3600.0 + 0.01, host[-1] + 0.01)
    assert clock.jumps == 1 and clock.last_jump_s == pytest.approx(-3600.0, abs=0.01)
    assert abs(t_jump - (host[-1] + 0.01)) < 0.01
    # Set forward by a minute: the smaller offset is taken at once, and reported.
    t_fwd = clock.to_host(device[-1] + 60.02 - 3600.0, host[-1] + 0.02)
    assert clock.jumps == 2 and abs(t_fwd - (host[-1] + 0.02)) < 0.01


def test_the_emulator_stamps_a_trace_when_its_source_is_asked_not_after() -> None:
    """A source that takes 50 ms (the simulator on a loaded machine) must not make its traces 50 ms late."""
    from gprbot.drivers.gpr.sdk_api import AcquisitionSetup

    now = [100.0]
    asked: list[float] = []

    def slow_source(n: int) -> np.ndarray:
        asked.append(now[0])  # the simulator takes the antenna's position now
        now[0] += 0.05
        return source(n)

    emu = GprSdkEmulator(slow_source, rate_hz=RATE_HZ, device_clock=lambda: now[0])
    setup = AcquisitionSetup(PPT, 100.0, 4, -1000.0, 0.004)
    frames = b"".join(emu._frame(n, setup) for n in (1, 2, 3))
    parsed = [e for e in TraceStreamParser(PPT, 4).feed(frames) if isinstance(e, TraceFrame)]
    assert len(parsed) == 2  # the last one waits for the next header
    for frame, when in zip(parsed, asked, strict=False):
        assert frame.tv_sec + frame.tv_nsec * 1e-9 == pytest.approx(when, abs=1e-6)
