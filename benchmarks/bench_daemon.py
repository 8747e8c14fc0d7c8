"""Event-loop lag of the daemon at full sensor rates, e-stop latency and survey wall time.

The daemon runs on the simulated robot in this process (its emulators share the loop, as they would
not on the robot, so the figures are pessimistic): IMU 400 + 250 Hz, encoders 50 Hz, GPR 100 traces/s,
the 50 Hz motion loop, the run log and the inference worker process. A 10 ms ticker on the same loop
records how late each tick wakes, separately while the survey is driven and while it is
reconstructed. Then jog → estop → reset is repeated to time the e-stop path against the emulator.
Run: `.venv/bin/python -m benchmarks.bench_daemon [--lines 3 --length 0.6 --speed 0.2]`.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import statistics
import tempfile
import time

import numpy as np

from benchmarks.machine import machine_description
from gprbot.config import load_config
from gprbot.daemon import serve
from gprbot.robot.runtime import RobotRuntime


async def ticker(lags: dict[str, list[float]], phase: list[str], stop: asyncio.Event, period_s: float = 0.01) -> None:
    """Sleep period_s again and again; record how late each wake-up is, under the current phase."""
    loop = asyncio.get_running_loop()
    expected = loop.time() + period_s
    while not stop.is_set():
        await asyncio.sleep(max(0.0, expected - loop.time()))
        now = loop.time()
        lags.setdefault(phase[0], []).append(now - expected)
        expected = max(expected + period_s, now)


def summary(values: list[float]) -> str:
    """Median, p99 and max in ms."""
    ms = np.array(values) * 1000
    return f"median {np.median(ms):6.2f} ms  p99 {np.percentile(ms, 99):7.2f} ms  max {ms.max():7.1f} ms  (n={ms.size})"


async def bench(lines: int, length_m: float, speed_m_s: float, estops: int) -> None:
    """Run the daemon, a survey and the e-stop loop; print the figures."""
    cfg = load_config()
    survey = dataclasses.replace(cfg.survey, lines=lines, length_m=length_m, speed_m_s=speed_m_s,
                                 start_xy_m=(0.1, 0.2))
    with tempfile.TemporaryDirectory() as runs:
        cfg = dataclasses.replace(cfg, survey=survey, runs_dir=runs)
        stop, ticker_stop = asyncio.Event(), asyncio.Event()
        started: list[RobotRuntime] = []
        daemon = asyncio.create_task(serve(cfg, shell_port=0, stop=stop, on_ready=started.append))  # type: ignore[arg-type]
        while not started or started[0].shell is None:
            await asyncio.sleep(0.05)
        rt = started[0]
        await asyncio.sleep(1.0)  # the filter's at-rest initialisation
        lags: dict[str, list[float]] = {}
        phase = ["idle"]
        ticks = asyncio.create_task(ticker(lags, phase, ticker_stop))
        await asyncio.sleep(2.0)
        began = time.monotonic()
        run = rt.survey.start(survey)
        while run.state in ("starting", "running", "paused"):
            phase[0] = "driving" if run.state == "running" else "starting"
            await asyncio.sleep(0.05)
        driven = time.monotonic()
        phase[0] = "reconstructing"
        while run.state == "finishing":
            await asyncio.sleep(0.05)
        finished = time.monotonic()
        phase[0] = "idle after"
        await asyncio.sleep(1.0)
        ticker_stop.set()
        await ticks
        latencies = []
        emulator = rt.sim.motors if rt.sim is not None else None
        for _ in range(estops):
            rt.jog.jog(0.2, 0.0, 2.0, rt.clock())
            await asyncio.sleep(0.3)
            latencies.append(await rt.estop())
            if emulator is not None:
                assert all(emulator.commanded_speed(a, c) == 0 for a, c in cfg.motors.wheel_map)
            rt.estopped = False
        stop.set()
        await daemon
    print(f"machine: {machine_description()}")
    print(f"survey: {lines} lines x {length_m} m at {speed_m_s} m/s, state {run.state}, pipes {run.pipes}; "
          f"driven in {driven - began:.1f} s (plan {run.plan.duration_s:.1f} s), "
          f"reconstructed in {finished - driven:.1f} s")
    print(f"run log: {rt.recorder.records} records")
    print("event-loop lag of a 10 ms ticker:")
    for name in ("idle", "driving", "reconstructing", "idle after"):
        if lags.get(name):
            print(f"  {name:15s} {summary(lags[name])}")
    print(f"e-stop, handler to wheels stopped (confirmed by the controllers), {estops} times: "
          f"median {statistics.median(latencies) * 1000:.2f} ms, max {max(latencies) * 1000:.2f} ms")


def main() -> None:
    """Parse the arguments and run the benchmark."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--lines", type=int, default=3)
    parser.add_argument("--length", type=float, default=0.6)
    parser.add_argument("--speed", type=float, default=0.2)
    parser.add_argument("--estops", type=int, default=10)
    args = parser.parse_args()
    asyncio.run(bench(args.lines, args.length, args.speed, args.estops))


if __name__ == "__main__":
    main()
