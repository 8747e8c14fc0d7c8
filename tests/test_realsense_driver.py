"""RealsenseDriver: recordings made with rs.software_device + rs.recorder, played back through the real
driver path; reconnection, stalls and drops with a scripted stand-in source."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gprbot.config import RealsenseConfig
from gprbot.drivers.realsense.clock import FramePairer
from gprbot.drivers.realsense.driver import Handoff, RealsenseDriver
from gprbot.drivers.realsense.recording import SoftwareD435i, write_recording
from gprbot.drivers.realsense.source import MotionReading, Reading, RealsenseSource, SourceEvent
from gprbot.errors import DriverError
from gprbot.messages import ImuSample, RawRgbdFrame, decode, encode
from tests.aio import within

rs = pytest.importorskip("pyrealsense2")

H, W = 240, 424
INTRINSICS = (300.0, 301.0, 211.5, 119.5)
T0 = 5.0  # device time of the first sample (s)


class Truth:
    """What was recorded: IMU samples and RGB-D frames with their device times."""

    def __init__(self, seed: int = 0):
        rng = np.random.default_rng(seed)
        self.gyro_t = T0 + np.arange(400) / 400.0
        self.accel_t = T0 + np.arange(250) / 250.0
        self.frame_t = T0 + np.arange(30) / 30.0
        self.gyro = rng.normal(0.0, 0.5, (400, 3))
        self.accel = rng.normal(0.0, 9.8, (250, 3))
        self.color = rng.integers(0, 256, (30, H, W, 3), dtype=np.uint8)
        self.depth = rng.integers(0, 65536, (30, H, W), dtype=np.uint16)

    def write(self, path: Path, compress: bool = False, color_format: str = "bgr8") -> Path:
        imu = [ImuSample(t, gyro=g) for t, g in zip(self.gyro_t, self.gyro, strict=True)]
        imu += [ImuSample(t, accel=a) for t, a in zip(self.accel_t, self.accel, strict=True)]
        frames = list(zip(self.frame_t, self.color, self.depth, strict=True))
        return write_recording(path, imu, frames, INTRINSICS, compress=compress, color_format=color_format)


@pytest.fixture(scope="module")
def truth() -> Truth:
    return Truth()


@pytest.fixture(scope="module")
def recording(truth: Truth, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return truth.write(tmp_path_factory.mktemp("rs") / "one_second.bag")


async def play(path: Path, clock: Callable[[], float] = time.monotonic) -> tuple[list[object], RealsenseDriver]:
    driver = RealsenseDriver(RealsenseConfig(playback=str(path)), clock=clock)
    await driver.start()
    messages = [m async for m in driver]
    await driver.close()
    return messages, driver


def split(messages: list[object]) -> tuple[list[ImuSample], list[ImuSample], list[RawRgbdFrame]]:
    gyro = [m for m in messages if isinstance(m, ImuSample) and m.gyro is not None]
    accel = [m for m in messages if isinstance(m, ImuSample) and m.accel is not None]
    frames = [m for m in messages if isinstance(m, RawRgbdFrame)]
    return gyro, accel, frames


def test_recorder_writes_db3_whatever_suffix_is_asked(recording: Path) -> None:
    assert recording.name == "one_second.db3" and recording.stat().st_size > 30 * H * W * 5


async def test_playback_returns_every_sample_with_its_values_and_device_spacing(
    recording: Path, truth: Truth
) -> None:
    messages, driver = await play(recording, clock=lambda: 50.0)
    gyro, accel, frames = split(messages)
    assert (len(gyro), len(accel), len(frames)) == (400, 250, 30)
    # Motion data travel as float32 in librealsense.
    assert np.array_equal([m.gyro for m in gyro], truth.gyro.astype(np.float32).astype(np.float64))
    assert np.array_equal([m.accel for m in accel], truth.accel.astype(np.float32).astype(np.float64))
    for frame, color, depth in zip(frames, truth.color, truth.depth, strict=True):
        assert np.array_equal(frame.color, color) and np.array_equal(frame.depth, depth)
    assert [f.number for f in frames] == list(range(30))
    assert (frames[0].fx, frames[0].fy, frames[0].cx, frames[0].cy) == INTRINSICS
    assert frames[0].depth_scale == pytest.approx(0.001)
    # One offset for every stream: anchored on the first sample received, at the injected host time.
    for got, device_t in ((gyro, truth.gyro_t), (accel, truth.accel_t), (frames, truth.frame_t)):
        assert np.allclose([m.t for m in got], 50.0 + device_t - T0, atol=1e-6)
    assert np.all(np.diff([m.t for m in messages]) >= -1e-6)  # recorded in time order, played in order
    assert driver.clock_jumps == 0


async def test_playback_health_shows_recorded_rates_and_no_drops(recording: Path) -> None:
    driver = RealsenseDriver(RealsenseConfig(playback=str(recording)))
    async with driver:
        connected = {name: h.connected for name, h in driver.streams().items()}
        count = sum([1 async for _ in driver])
        health = driver.streams()
    assert count == 680 and all(connected.values())
    assert {name: round(h.rate_hz) for name, h in health.items()} == {
        "gyro": 400, "accel": 250, "depth": 30, "color": 30
    }
    assert all(h.drops == 0 and h.errors == 0 for h in health.values())
    assert driver.device_info["serial"] == "000000000000"


async def test_playback_on_the_host_clock_is_anchored_at_the_start(recording: Path, truth: Truth) -> None:
    before = time.monotonic()
    messages, _ = await play(recording)
    gyro, _, frames = split(messages)
    assert before <= gyro[0].t <= time.monotonic()
    assert np.allclose(np.array([m.t for m in frames]) - gyro[0].t, truth.frame_t - T0, atol=1e-6)


async def test_compressed_rgb8_recording_is_lossless_and_published_as_bgr(tmp_path: Path) -> None:
    truth = Truth(seed=3)
    path = truth.write(tmp_path / "png.db3", compress=True, color_format="rgb8")
    _, _, frames = split((await play(path))[0])
    assert len(frames) == 30
    assert all(np.array_equal(f.depth, d) for f, d in zip(frames, truth.depth, strict=True))
    assert all(np.array_equal(f.color, c[..., ::-1]) for f, c in zip(frames, truth.color, strict=True))


async def test_depth_is_registered_to_a_colour_camera_with_other_intrinsics(tmp_path: Path) -> None:
    color_intr, baseline = (150.0, 150.0, 212.0, 120.0), 0.015
    depth = np.full((H, W), 2000, np.uint16)  # a wall 2 m away
    frames = [(0.0, np.zeros((H, W, 3), np.uint8), depth)] * 3
    path = write_recording(tmp_path / "align.db3", [], frames, (200.0, 200.0, 212.0, 120.0),
                           color_intrinsics=color_intr, depth_to_color_m=(baseline, 0.0, 0.0))
    _, _, got = split((await play(path))[0])
    assert (got[0].fx, got[0].cx) == (150.0, 212.0)
    # The depth image spans x/z in [-212, 211]/200 and y/z in [-120, 119]/200; seen by the colour camera,
    # shifted by f * baseline / z pixels.
    shift = 150.0 * baseline / 2.0
    u0, u1 = 212 + 150 * (-212 / 200) + shift, 212 + 150 * (211 / 200) + shift
    v0, v1 = 120 + 150 * (-120 / 200), 120 + 150 * (119 / 200)
    aligned = got[0].depth
    assert np.all(aligned[int(v0) + 2:int(v1) - 1, int(u0) + 2:int(u1) - 1] == 2000)
    assert not aligned[:, :int(u0) - 1].any() and not aligned[:, int(u1) + 2:].any()
    assert not aligned[:int(v0) - 1].any() and not aligned[int(v1) + 2:].any()


async def test_live_path_pairs_frames_and_converts_on_the_minimum_delay(truth: Truth) -> None:
    """A software device stands in for the camera: the driver opens and streams it exactly as a D435i."""
    camera = SoftwareD435i(W, H, INTRINSICS, serial="live-1")
    host0, latency, now = 100.0, 0.001, [0.0]
    driver = RealsenseDriver(
        RealsenseConfig(source="device", width=W, height=H, fps=30), clock=lambda: now[0], queue_size=4096,
        frame_queue_size=30,  # the whole second is pushed at once, faster than any loop takes it
        source_factory=lambda cfg, sink, clock: RealsenseSource(cfg, sink, clock, device=camera.device),
    )
    events = [(t, "gyro", g) for t, g in zip(truth.gyro_t, truth.gyro, strict=True)]
    events += [(t, "accel", a) for t, a in zip(truth.accel_t, truth.accel, strict=True)]
    events += [(t, "depth", d) for t, d in zip(truth.frame_t, truth.depth, strict=True)]
    events += [(t + 0.003, "color", c) for t, c in zip(truth.frame_t, truth.color, strict=True)]  # not in sync

    def stream() -> None:
        for t, name, data in sorted(events, key=lambda e: e[0]):
            now[0] = host0 + (t - T0) + latency  # received 1 ms after it was taken
            camera.push(name, t, data)

    await driver.start()
    await asyncio.to_thread(stream)
    got = await take(driver, 680, types=(ImuSample, RawRgbdFrame))
    health = driver.streams()
    await driver.close()
    gyro, accel, frames = split(list(got))
    assert (len(gyro), len(accel), len(frames)) == (400, 250, 30)
    assert np.array_equal([m.gyro for m in gyro], truth.gyro.astype(np.float32).astype(np.float64))
    assert all(np.array_equal(f.depth, d) and np.array_equal(f.color, c)
               for f, d, c in zip(frames, truth.depth, truth.color, strict=True))
    for got_t, device_t in ((gyro, truth.gyro_t), (accel, truth.accel_t), (frames, truth.frame_t)):
        assert np.allclose([m.t for m in got_t], host0 + device_t - T0 + latency, atol=1e-6)
    assert all(h.connected and h.drops == 0 for h in health.values())
    assert driver.device_info["serial"] == "live-1" and driver.clock_jumps == 0


async def test_stop_in_the_middle_of_a_playback_returns(recording: Path) -> None:
    driver = RealsenseDriver(RealsenseConfig(playback=str(recording)), queue_size=4)
    await driver.start()
    seen = 0
    async for _ in driver:
        seen += 1
        if seen == 5:
            break
    await within(driver.close(), 10.0)
    assert [m async for m in driver] == []


def test_rgbd_frame_round_trips_through_the_run_log_codec() -> None:
    frame = RawRgbdFrame(1.5, 7, np.ones((4, 6, 3), np.uint8), np.arange(24, dtype=np.uint16).reshape(4, 6),
                      0.001, 300.0, 301.0, 3.0, 2.0)
    back = decode(encode(frame))
    assert isinstance(back, RawRgbdFrame) and back.number == 7 and back.fx == 300.0
    assert np.array_equal(back.depth, frame.depth) and back.depth.dtype == np.uint16


@pytest.mark.parametrize(
    ("cfg", "words"),
    [
        (RealsenseConfig(playback="/nonexistent/run.db3"), ["/nonexistent/run.db3", "path"]),
        (RealsenseConfig(source="sim"), ["simulator", "realsense.playback"]),
        (RealsenseConfig(source="device", gyro_hz=300), ["gyro_hz", "200", "400"]),
    ],
)
async def test_unusable_sources_say_what_to_check(cfg: RealsenseConfig, words: list[str]) -> None:
    with pytest.raises(DriverError) as info:
        await RealsenseDriver(cfg).start()
    assert all(word in str(info.value) for word in words)


async def test_a_file_that_is_not_a_recording_is_reported(tmp_path: Path) -> None:
    junk = tmp_path / "notes.db3"
    junk.write_text("not sqlite")
    with pytest.raises(DriverError, match=r"cannot read .*notes\.db3"):
        await RealsenseDriver(RealsenseConfig(playback=str(junk))).start()


async def test_no_camera_attached_points_at_usb3_and_udev() -> None:
    if len(rs.context().query_devices()) > 0:
        pytest.skip("a RealSense is attached to this machine")
    with pytest.raises(DriverError, match=r"USB 3.*udev"):
        await RealsenseDriver(RealsenseConfig(source="device")).start()


def test_pairer_matches_within_half_a_frame_and_drops_the_unmatched() -> None:
    pairer: FramePairer[str] = FramePairer(tolerance_ms=16.0)
    assert pairer.offer("depth", 0.0, "d0") is None
    assert pairer.offer("color", 1.0, "c0") == ("d0", "c0")
    assert pairer.offer("color", 33.0, "c1") is None
    assert pairer.offer("color", 66.0, "c2") is None  # c1 never found its depth
    assert pairer.offer("depth", 100.0, "d3") is None  # c2 too old for it: discarded
    assert pairer.offer("color", 99.0, "c3") == ("d3", "c3")


async def test_handoff_drops_when_live_and_blocks_when_playing_back() -> None:
    loop = asyncio.get_running_loop()
    live = Handoff(loop, maxsize=2, block=False)
    assert [live.put(SourceEvent("error", str(i))) for i in range(3)] == [True, True, False]
    assert live.put(SourceEvent("lost"), force=True)
    assert [e.kind for e in live.take_all() if isinstance(e, SourceEvent)] == ["error", "error", "lost"]
    playback = Handoff(loop, maxsize=1, block=True)
    results: list[bool] = []
    producer = threading.Thread(target=lambda: results.extend(playback.put(SourceEvent(str(i))) for i in range(3)))
    producer.start()
    got: list[Reading] = []
    async with asyncio.timeout(5.0):
        while len(got) < 3:
            await playback.wait()
            got += playback.take_all()
    await asyncio.to_thread(producer.join)
    assert results == [True, True, True] and [e.kind for e in got if isinstance(e, SourceEvent)] == ["0", "1", "2"]
    playback.close()
    assert playback.closed and playback.take_all() == []


class ScriptedSource:
    """A stand-in source: emits gyro readings (number, device ms, host s) from a thread, then maybe more."""

    def __init__(self, sink: Callable[[Reading], None], script: list[Reading] | None):
        self.sink, self.script = sink, script
        self.is_playback, self.streams = False, ("gyro",)
        self.device_info = {"source": "scripted"}
        self.closed = threading.Event()

    def open(self) -> None:
        if self.script is None:
            raise DriverError("no RealSense camera found (scripted)")
        threading.Thread(target=lambda: [self.sink(r) for r in self.script or []]).start()

    def close(self) -> None:
        self.closed.set()

    def wait_finished(self, timeout_s: float | None = None) -> bool:
        return self.closed.wait(timeout_s)


def gyro(numbers: list[int], device_ms0: float, host_s0: float) -> list[Reading]:
    return [MotionReading("gyro", n, device_ms0 + 2.5 * n, "hardware_clock", host_s0 + 0.0025 * n + 0.001,
                          np.array([n, 0.0, 0.0])) for n in numbers]


def scripted(scripts: list[list[Reading] | None], **kwargs: float) -> RealsenseDriver:
    queue = list(scripts)

    def factory(cfg: RealsenseConfig, sink: Callable[[Reading], None], clock: object) -> ScriptedSource:
        return ScriptedSource(sink, queue.pop(0))

    return RealsenseDriver(RealsenseConfig(source="device"), source_factory=factory,
                           backoff_initial_s=0.01, backoff_max_s=0.02, **kwargs)


async def take(driver: RealsenseDriver, count: int, types: tuple[type, ...] = (ImuSample,)) -> list[Any]:
    got: list[Any] = []
    async with asyncio.timeout(10.0):
        async for message in driver:
            assert isinstance(message, types)
            got.append(message)
            if len(got) == count:
                break
    return got


async def test_lost_device_is_reopened_with_backoff_and_its_new_clock_anchored() -> None:
    first = [*gyro(list(range(10)), 100_000.0, 10.0), SourceEvent("lost", "unplugged")]
    again = gyro(list(range(10)), 0.0, 20.0)  # after a re-plug the device clock and numbers restart
    driver = scripted([first, None, again], stall_timeout_s=5.0)
    await driver.start()
    got = await take(driver, 20)
    health = driver.streams()["gyro"]
    await driver.close()
    expected = [10.001 + 0.0025 * n for n in range(10)] + [20.001 + 0.0025 * n for n in range(10)]
    assert np.allclose([m.t for m in got], expected, atol=1e-9)
    assert driver.reconnects == 1 and driver.clock_jumps == 0
    assert health.connected and health.drops == 0
    assert health.errors == 2 and health.last_error == "no RealSense camera found (scripted)"


async def test_a_silent_device_counts_as_lost() -> None:
    driver = scripted([gyro([0, 1, 2], 0.0, 1.0), gyro([0, 1, 2], 0.0, 2.0)], stall_timeout_s=0.1)
    await driver.start()
    got = await take(driver, 6)
    await driver.close()
    assert [m.t for m in got][3] == pytest.approx(2.001)
    assert driver.reconnects == 1
    assert "no frames for 0.1 s" in str(driver.streams()["gyro"].last_error)


async def test_frame_number_gaps_are_drops_and_errors_are_recorded() -> None:
    script = [*gyro([0, 1, 2, 5, 6, 9], 0.0, 1.0), SourceEvent("error", "RuntimeError: bad frame")]
    driver = scripted([script, None], stall_timeout_s=5.0)
    await driver.start()
    await take(driver, 6)
    async with asyncio.timeout(5.0):
        while driver.streams()["gyro"].errors == 0:  # the error event follows from the source's thread
            await asyncio.sleep(0.001)
    health = driver.streams()
    await driver.close()
    assert health["gyro"].drops == 4
    assert health["gyro"].last_error == "RuntimeError: bad frame"
    assert not health["depth"].connected and "no depth stream" in str(health["depth"].last_error)
