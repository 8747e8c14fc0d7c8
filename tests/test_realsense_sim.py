"""The simulated D435i on the live driver path (drivers/realsense/emulator) and the IMU's axes (issue 14)."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import numpy as np
import pytest

from gprbot.config import RealsenseConfig
from gprbot.drivers.realsense.driver import RealsenseDriver
from gprbot.geometry import CameraMount
from gprbot.messages import ImuSample, RawRgbdFrame

rs = pytest.importorskip("pyrealsense2")

from gprbot.drivers.realsense.emulator import DEVICE_BOOT_OFFSET_S, D435iEmulator  # noqa: E402
from gprbot.drivers.realsense.recording import write_recording  # noqa: E402

H, W = 60, 80
INTRINSICS = (70.0, 70.0, 39.5, 29.5)
MOUNT = CameraMount(pitch_down_deg=60.0)


async def test_the_imu_arrives_in_base_link_axes(tmp_path: Path) -> None:
    # At rest on a level floor: specific force +g along base z, a slow turn about base z, both as the
    # pitched-down camera reports them (its optical axes).
    to_camera = MOUNT.rotation().T
    accel_cam, gyro_cam = to_camera @ np.array([0.0, 0.0, 9.80665]), to_camera @ np.array([0.0, 0.0, 0.01])
    assert abs(accel_cam[1]) > 4.0  # the camera's y (down) sees much of gravity: unrotated it would tilt the filter
    imu = [ImuSample(5.0 + i / 400, gyro=gyro_cam) for i in range(40)] + [
        ImuSample(5.0 + i / 250, accel=accel_cam) for i in range(25)]
    frames = [(5.0, np.zeros((H, W, 3), np.uint8), np.zeros((H, W), np.uint16))]
    path = write_recording(tmp_path / "rest.db3", imu, frames, INTRINSICS)
    driver = RealsenseDriver(RealsenseConfig(playback=str(path)), imu_to_base=MOUNT.rotation())
    async with driver:
        messages = [m async for m in driver]
    gyro = np.array([m.gyro for m in messages if isinstance(m, ImuSample) and m.gyro is not None])
    accel = np.array([m.accel for m in messages if isinstance(m, ImuSample) and m.accel is not None])
    assert len(gyro) == 40 and len(accel) == 25
    assert np.allclose(gyro, [0.0, 0.0, 0.01], atol=1e-6)  # float32 in librealsense
    assert np.allclose(accel, [0.0, 0.0, 9.80665], atol=1e-5)


async def test_the_emulator_is_opened_and_streamed_like_a_camera_on_usb() -> None:
    cfg = RealsenseConfig(source="sim", width=W, height=H, fps=30)
    rng = np.random.default_rng(0)
    color = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    depth = np.full((H, W), 500, dtype=np.uint16)
    rendered: list[float] = []

    def render(t: float) -> tuple[np.ndarray, np.ndarray]:
        rendered.append(t)
        return color, depth

    emulator = D435iEmulator(cfg, INTRINSICS, time.monotonic, render)
    assert emulator.device_ms(DEVICE_BOOT_OFFSET_S + 1.0) == pytest.approx(1000.0)  # a clock of its own
    driver = RealsenseDriver(cfg, source_factory=emulator.source_factory)
    await driver.start()
    emulator.start()
    received: list[object] = []

    async def feed_imu() -> None:
        for _ in range(50):  # 0.5 s of gyro at 400 Hz, pushed in 10 ms batches as the simulator does
            now = time.monotonic()
            for k in range(4):
                emulator.push_imu(now - 0.0075 + k * 0.0025, gyro=np.array([0.0, 0.0, 0.1]))
            await asyncio.sleep(0.01)

    async def consume() -> None:
        async for message in driver:
            received.append(message)

    consumer = asyncio.create_task(consume())
    await feed_imu()
    emulator.stop()
    await asyncio.sleep(0.2)
    health = driver.streams()
    await driver.close()
    await consumer
    frames = [m for m in received if isinstance(m, RawRgbdFrame)]
    gyro = [m for m in received if isinstance(m, ImuSample)]
    assert len(gyro) == 200 and len(frames) >= 10
    assert np.array_equal(frames[0].color, color) and np.array_equal(frames[0].depth, depth)
    assert frames[0].depth_scale == pytest.approx(0.001) and (frames[0].fx, frames[0].cx) == (70.0, 39.5)
    # Device times converted to host time: each frame is stamped with the time it was rendered for.
    stamps = np.array([f.t for f in frames])
    assert np.allclose(stamps, np.array(rendered[:len(frames)]), atol=0.005)
    assert health["gyro"].drops == 0 and health["depth"].drops == 0 and health["gyro"].connected
    assert driver.device_info["serial"] == "sim-d435i"


async def test_a_stalled_loop_costs_stale_frames_never_imu_samples() -> None:
    from gprbot.drivers.realsense.handoff import Handoff
    from gprbot.drivers.realsense.readings import MotionReading, RgbdReading

    handoff = Handoff(asyncio.get_running_loop(), maxsize=4096, block=False, max_frames=2)
    image, depth = np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2), np.uint16)
    for k in range(650):  # a second of IMU with 30 frames among it, while the loop takes nothing
        assert handoff.put(MotionReading("gyro", k, k * 2.5, "hardware_clock", 0.0, np.zeros(3)))
        if k % 22 == 0:
            assert handoff.put(RgbdReading(k, k, k * 2.5, "hardware_clock", 0.0, image, depth, 0.001, INTRINSICS))
    items = handoff.take_all()
    motion = [i for i in items if isinstance(i, MotionReading)]
    frames = [i for i in items if isinstance(i, RgbdReading)]
    assert [m.number for m in motion] == list(range(650))
    assert [f.depth_number for f in frames] == [616, 638]  # the newest two
    assert handoff.frames_dropped == 28
