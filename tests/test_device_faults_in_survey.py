"""Issue 15 fault harness: a device link fails during a survey (motor cable unplugged, motor replies
lost, GPR unplugged, stalled, garbage, power cycle). The wheels stop, the drivers reconnect, the survey
pauses, marks the line interrupted and resumes by itself, and the run log loses nothing.

The suite runs one fault (about 20 s); `python -m benchmarks.bench_device_faults` runs all of them
(GPRBOT_FAULT_MATRIX=all) and prints the wheels-stopped latencies."""

from __future__ import annotations

import asyncio
import os
import socket
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest

from gprbot.robot.runtime import RobotRuntime
from gprbot.runlog_reader import RunLogReader
from tests.test_daemon import ShellClient, notify_socket, running_daemon  # noqa: F401


async def _unplug_motors(rt: RobotRuntime) -> None:
    assert rt.sim is not None
    rt.sim.motors.unplug()
    await asyncio.sleep(0.6)
    rt.sim.motors.replug()


async def _motor_replies_lost(rt: RobotRuntime) -> None:
    assert rt.sim is not None
    rt.sim.motors.drop_replies(12)


async def _gpr_unplugged(rt: RobotRuntime) -> None:
    assert rt.sim is not None
    rt.sim.gpr.unplug(mid_frame=True)


async def _gpr_stall(rt: RobotRuntime) -> None:
    assert rt.sim is not None
    rt.sim.gpr.stall()
    await asyncio.sleep(2.0)
    rt.sim.gpr.resume()


async def _gpr_garbage(rt: RobotRuntime) -> None:
    assert rt.sim is not None
    rt.sim.gpr.inject_noise(4096, inside_frame=True)


async def _gpr_power_cycle(rt: RobotRuntime) -> None:
    assert rt.sim is not None
    rt.sim.gpr.power_cycle()


FAULTS: dict[str, Callable[[RobotRuntime], Awaitable[None]]] = {
    "motor cable unplugged": _unplug_motors, "motor replies lost": _motor_replies_lost,
    "gpr unplugged": _gpr_unplugged, "gpr stalled": _gpr_stall, "gpr garbage": _gpr_garbage,
    "gpr power cycle": _gpr_power_cycle,
}


SUITE_FAULTS = ["motor replies lost"]


@pytest.mark.slow
@pytest.mark.timeout(120)
@pytest.mark.parametrize("fault", list(FAULTS) if os.environ.get("GPRBOT_FAULT_MATRIX") == "all" else SUITE_FAULTS)
async def test_a_device_fault_mid_line_pauses_resumes_and_loses_nothing(
        tmp_path: Path, notify_socket: socket.socket, fault: str) -> None:  # noqa: F811
    async with running_daemon(tmp_path, use_worker=False) as (rt, client, _, _):
        assert rt.sim is not None
        emulator, wheel_map = rt.sim.motors, rt.cfg.motors.wheel_map
        assert (await client.command("survey start lines=2")).ok
        await client.wait_event("line 0 start", timeout_s=20)
        async with asyncio.timeout(10):  # driving (a transient fault under CPU load may pause it first)
            while min(abs(emulator.commanded_speed(a, c)) for a, c in wheel_map) < 0.5:
                await asyncio.sleep(0.05)
        loop = asyncio.get_running_loop()
        began = loop.time()
        injected = asyncio.create_task(FAULTS[fault](rt))
        if fault.startswith("motor"):
            while any(emulator.commanded_speed(a, c) != 0 for a, c in wheel_map):
                await asyncio.sleep(0.005)
            seen_after = loop.time() - began
            # When each wheel's target became 0 (a serial stop or the failsafe's trip, which the emulator
            # logs at the instant a controller's firmware would act), not when this 5 ms poll saw it.
            zeroed = [min((e.t for e in emulator.command_log if (e.address, e.channel) == wheel
                           and e.t >= began and e.counts_per_s == 0.0), default=loop.time()) for wheel in wheel_map]
            stopped_after = max(zeroed) - began
            # The controllers' failsafe (0.1 s) or the driver's stop after its retries, whichever comes first;
            # the figure (target <= 100 ms) is printed for the report, the bound only catches "never".
            print(f"\nfault {fault!r}: wheels commanded to 0 after {stopped_after * 1000:.0f} ms "
                  f"(seen by the test's poll after {seen_after * 1000:.0f} ms)")
            assert stopped_after < 1.0, stopped_after
        await injected
        done = await client.wait_event("survey done", timeout_s=90)
        assert "survey done" in done
        run = rt.survey.current
        assert run is not None and run.state == "done"
        if fault not in ("gpr garbage",):  # garbage costs a trace or two, not the link
            assert run.interruptions, client.events
            assert any(e.startswith("survey line 0 interrupted") for e in client.events)
        log = RunLogReader(run.run_dir)
        records = sum(1 for _ in log)
        assert log.ended and not log.torn and log.skipped == 0 and records > 0
        assert sorted(run.bscans) == [0, 1]
