"""RoboClaw packet serial: parser throughput and the driver's cycle and fault-to-stop times, beside the need.

The need: 3 wheels × (count + speed) at 50 Hz = 300 read replies/s plus 100 acknowledged speed
packets/s. Prints medians of: CRC16 rate, reply-parser rate (replies/s), one full driver cycle
(set speeds + read encoders) against the emulator over a pty, the serial line time one cycle needs
at common baud rates, and the time from an injected fault to all wheels commanded to 0.
Run: `.venv/bin/python -m benchmarks.bench_parsers_motors`.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmarks.machine import machine_description
from gprbot.config import MotorsConfig
from gprbot.drivers.motors import protocol as rc
from gprbot.drivers.motors import replies
from gprbot.drivers.motors.device_side import encode_read_reply
from gprbot.drivers.motors.driver import MotorDriver
from gprbot.drivers.motors.emulator import RoboClawEmulator
from gprbot.errors import DriverError
from gprbot.messages import WheelSpeeds

NEED_REPLIES_PER_S = 3 * 2 * 50
CFG = MotorsConfig(command_timeout_s=0.02, retries=2, failsafe_timeout_s=0.1, max_wheel_accel_rad_s2=400.0)




def median_rate(work: Callable[[], int], repeats: int) -> float:
    """Median items/s of `work()` (which returns how many items it processed)."""
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        items = work()
        rates.append(items / (time.perf_counter() - start))
    return statistics.median(rates)


def bench_parsers(repeats: int) -> None:
    """CRC and reply parsing, pure CPU."""
    request = rc.read_encoder(0x80, 1)
    reply = encode_read_reply(0x80, request.command, bytes.fromhex("0001234502"))
    packet = rc.drive_speeds_accel(0x80, 6519, 1630, -815).encode()

    def parse_replies() -> int:
        for _ in range(20_000):
            replies.ReplyParser(request).feed(reply)
        return 20_000

    def encode_packets() -> int:
        for _ in range(20_000):
            rc.drive_speeds_accel(0x80, 6519, 1630, -815).encode()
        return 20_000

    def crc_bytes() -> int:
        data = packet * 4000
        rc.crc16(data)
        return len(data)

    crc_bytes_per_s = median_rate(crc_bytes, repeats)
    parse = median_rate(parse_replies, repeats)
    print(f"CRC16:               {crc_bytes_per_s / 1e6:8.2f} MB/s")
    print(f"encoder reply parse: {parse:10.0f} replies/s  ({parse / NEED_REPLIES_PER_S:.0f}× the need of "
          f"{NEED_REPLIES_PER_S}/s)")
    print(f"speed packet encode: {median_rate(encode_packets, repeats):10.0f} packets/s")


def line_time_per_cycle() -> None:
    """Bytes on the wire for one 50 Hz cycle, and the time they take at common baud rates (10 bits/byte)."""
    writes = [rc.drive_speeds_accel(128, 1, 0, 0), rc.drive_speed_accel(129, 1, 0, 1)]
    reads = [f(a, c) for a, c in CFG.wheel_map for f in (rc.read_encoder, rc.read_speed)]
    n_bytes = sum(len(r.encode()) + 1 for r in writes) + sum(len(r.encode()) + 7 for r in reads)
    times = ", ".join(f"{baud}: {n_bytes * 10 / baud * 1000:.1f} ms" for baud in (38400, 115200, 460800))
    print(f"line time per cycle ({n_bytes} bytes; budget 20 ms at 50 Hz; USB ignores baud): {times}")


async def bench_driver(cycles: int, faults: int) -> None:
    """A full cycle over the pty, then fault-to-stop latencies for a silent controller."""
    with tempfile.TemporaryDirectory() as tmp:
        emu = RoboClawEmulator(counts_per_rev=CFG.encoder_counts_per_rev)
        path = emu.serve_pty(Path(tmp) / "roboclaw")
        driver = MotorDriver(dataclasses.replace(CFG, port=path), sleep=lambda d: asyncio.sleep(d / 20))
        await driver.start()
        speeds = WheelSpeeds(0.0, np.array([5.0, -5.0, 2.0]))
        durations = []
        for _ in range(cycles):
            start = time.perf_counter()
            await driver.set_wheel_speeds(speeds)
            await driver.read_encoders()
            durations.append(time.perf_counter() - start)
        cycle = statistics.median(durations)
        print(f"driver cycle over pty (set speeds + read 3 encoders): median {cycle * 1e3:.2f} ms, "
              f"p99 {np.percentile(durations, 99) * 1e3:.2f} ms → {1 / cycle:.0f} cycles/s (need 50)")
        latencies: list[float] = []
        rng = np.random.default_rng(0)
        for _ in range(faults):
            await driver.wait_connected()
            await asyncio.sleep(0.05)
            await driver.set_wheel_speeds(speeds)
            into_period = 0.02 * rng.random()  # the fault strikes anywhere in a 50 Hz period
            await asyncio.sleep(into_period)
            t_fault = time.monotonic()
            emu.drop_replies()
            await asyncio.sleep(0.02 - into_period)
            with contextlib.suppress(DriverError):
                await driver.read_encoders()
            await asyncio.sleep(0.03)  # let the emulator read what the driver wrote
            first_zero: dict[tuple[int, int], float] = {}
            for e in emu.command_log:
                if e.t >= t_fault and e.counts_per_s == 0.0:
                    first_zero.setdefault((e.address, e.channel), e.t)
            latencies.append(max(first_zero.values(), default=float("nan")) - t_fault)
            emu.clear_faults()
        print(f"silent controller → all wheels commanded 0: median {statistics.median(latencies) * 1e3:.1f} ms, "
              f"max {max(latencies) * 1e3:.1f} ms (bound 100 ms; detection = 3 × {CFG.command_timeout_s * 1e3:.0f} ms)")
        await driver.close()
        emu.close()


def main() -> None:
    """Print the figures."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cycles", type=int, default=500)
    parser.add_argument("--faults", type=int, default=10)
    args = parser.parse_args()
    print(machine_description())
    bench_parsers(args.repeats)
    line_time_per_cycle()
    asyncio.run(bench_driver(args.cycles, args.faults))


if __name__ == "__main__":
    main()
