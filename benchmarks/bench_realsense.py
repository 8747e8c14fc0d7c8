"""RealSense driver throughput: messages handled per second beside the D435i's rates (IMU 400 + 250 Hz,
RGB-D 30 fps).

1. conversion path alone: readings through the handoff, clock conversion, health and message build
   (a stand-in source pushes pre-built readings from a thread, so no SDK cost is counted);
2. playback: a recording played through the real driver (db3 read, librealsense callbacks, numpy copies,
   depth/colour pairing), at 424x240 and 640x480, with and without depth-to-colour registration;
3. live path: a software device streaming through the real driver (the SDK's frame callbacks).
Each figure is the median of several runs. Run: `.venv/bin/python -m benchmarks.bench_realsense`.
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmarks.machine import machine_description as describe_machine
from gprbot.config import RealsenseConfig
from gprbot.drivers.realsense.driver import RealsenseDriver
from gprbot.drivers.realsense.readings import MotionReading, Reading, RgbdReading
from gprbot.drivers.realsense.recording import SoftwareD435i, write_recording
from gprbot.drivers.realsense.source import RealsenseSource
from gprbot.messages import ImuSample, RawRgbdFrame

IMU_HZ, FPS = 400 + 250, 30


def machine_description() -> str:
    """The machine, with the librealsense version."""
    import pyrealsense2 as rs

    return describe_machine(f"librealsense {rs.__version__}")



class PrebuiltSource:
    """Pushes ready-made readings from a thread: measures the driver's side only."""

    def __init__(self, sink: Callable[[Reading], None], readings: list[Reading]):
        self.sink, self.readings = sink, readings
        self.is_playback, self.streams, self.device_info = False, ("gyro", "accel", "depth", "color"), {}

    def open(self) -> None:
        threading.Thread(target=lambda: [self.sink(r) for r in self.readings], daemon=True).start()

    def close(self) -> None:
        pass

    def wait_finished(self, timeout_s: float | None = None) -> bool:
        return True


async def drain(
    driver: RealsenseDriver, count: int, feed: Callable[[], object] | None = None
) -> tuple[int, int, float]:
    """Start, run `feed` in a thread, take `count` messages, stop: (IMU samples, frames, seconds taken)."""
    start = time.perf_counter()
    await driver.start()
    feeding = asyncio.create_task(asyncio.to_thread(feed)) if feed else None
    imu = frames = 0
    async with asyncio.timeout(60.0):
        async for message in driver:
            imu += isinstance(message, ImuSample)
            frames += isinstance(message, RawRgbdFrame)
            if imu + frames == count:
                break
    seconds = time.perf_counter() - start
    if feeding:
        await feeding
    await driver.close()
    return imu, frames, seconds


def conversion_path(kind: str, n: int) -> float:
    """Messages per second through handoff + clock + health + message, for IMU or 640x480 RGB-D readings."""
    if kind == "imu":
        readings: list[Reading] = [
            MotionReading("gyro", i, 2.5 * i, "global_time", 1.0 + 0.0025 * i, np.zeros(3)) for i in range(n)
        ]
    else:
        color, depth = np.zeros((480, 640, 3), np.uint8), np.zeros((480, 640), np.uint16)
        readings = [RgbdReading(i, i, 33.3 * i, "global_time", 1.0 + 0.0333 * i, color, depth, 0.001,
                                (600.0, 600.0, 320.0, 240.0)) for i in range(n)]
    driver = RealsenseDriver(RealsenseConfig(source="device"), queue_size=n + 1,
                             source_factory=lambda cfg, sink, clock: PrebuiltSource(sink, readings))
    return n / asyncio.run(drain(driver, n))[2]


def recording(folder: Path, width: int, height: int, aligned: bool) -> Path:
    """One second at D435i rates of smooth synthetic images (a ramp of depths, a gradient image)."""
    rng = np.random.default_rng(0)
    imu = [(t, rng.normal(size=3), None) for t in np.arange(400) / 400.0]
    imu += [(t, None, rng.normal(size=3)) for t in np.arange(250) / 250.0]
    depth = (500 + np.add.outer(np.arange(height), np.arange(width)) % 3000).astype(np.uint16)
    color = np.dstack([np.full((height, width), c, np.uint8) for c in (40, 120, 200)])
    frames = [(i / 30.0, color, depth) for i in range(30)]
    f = 0.9 * width
    intr = (f, f, width / 2, height / 2)
    color_intr = (1.1 * f, 1.1 * f, width / 2, height / 2) if aligned else None
    return write_recording(folder / f"{width}x{height}{'_aligned' if aligned else ''}.db3", imu, frames, intr,
                           color_intrinsics=color_intr, depth_to_color_m=(0.015 if aligned else 0.0, 0.0, 0.0))


def playback(path: Path) -> float:
    """Seconds to play one second of recording through the real driver."""
    return asyncio.run(drain(RealsenseDriver(RealsenseConfig(playback=str(path))), 680))[2]


def live(width: int, height: int) -> float:
    """Seconds to stream one second of samples from a software device through the real driver."""
    camera = SoftwareD435i(width, height, (0.9 * width, 0.9 * width, width / 2, height / 2))
    depth, color = np.full((height, width), 1000, np.uint16), np.zeros((height, width, 3), np.uint8)
    events = sorted([(i / 400, "gyro", np.ones(3)) for i in range(400)] + [(i / 250, "accel", np.ones(3))
                     for i in range(250)] + [(i / 30, s, d) for i in range(30) for s, d in
                                             (("depth", depth), ("color", color))], key=lambda e: e[0])
    driver = RealsenseDriver(RealsenseConfig(source="device", width=width, height=height), queue_size=1024,
                             source_factory=lambda c, s, k: RealsenseSource(c, s, k, device=camera.device))

    def feed() -> None:
        for t, name, data in events:
            camera.push(name, t, data)

    return asyncio.run(drain(driver, 680, feed))[2]


def main(argv: list[str] | None = None) -> None:
    """Print the benchmark table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)
    median = statistics.median
    print(f"machine: {machine_description()}")
    print(f"real rates: IMU {IMU_HZ} samples/s (gyro 400 + accel 250), RGB-D {FPS} frames/s")
    imu = median(conversion_path("imu", 20000) for _ in range(args.repeats))
    rgbd = median(conversion_path("rgbd", 2000) for _ in range(args.repeats))
    print(f"conversion path: IMU {imu:,.0f} samples/s ({imu / IMU_HZ:,.0f}x real), RGB-D 640x480 "
          f"{rgbd:,.0f} frames/s ({rgbd / FPS:,.0f}x real)")
    print(f"{'1 s at D435i rates':<36}{'wall ms':>9}{'IMU/s':>10}{'frames/s':>10}{'x real':>8}")
    with tempfile.TemporaryDirectory() as folder:
        for width, height, aligned in ((424, 240, False), (640, 480, False), (640, 480, True)):
            path = recording(Path(folder), width, height, aligned)
            seconds = median(playback(path) for _ in range(args.repeats))
            label = f"playback {width}x{height}" + (" + registration" if aligned else "")
            print(f"{label:<36}{seconds * 1e3:>9.0f}{650 / seconds:>10,.0f}{30 / seconds:>10,.0f}{1 / seconds:>8.1f}")
    for width, height in ((424, 240), (640, 480)):
        seconds = median(live(width, height) for _ in range(args.repeats))
        label = f"live software device {width}x{height}"
        print(f"{label:<36}{seconds * 1e3:>9.0f}{650 / seconds:>10,.0f}{30 / seconds:>10,.0f}{1 / seconds:>8.1f}")


if __name__ == "__main__":
    main()
