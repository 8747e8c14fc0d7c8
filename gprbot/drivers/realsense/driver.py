"""Asyncio driver of the Intel RealSense D435i: IMU samples and registered RGB-D frames as messages.

The blocking SDK (`source.RealsenseSource`) runs in librealsense's threads and in worker threads, never
on the event loop; its readings cross into the loop through a bounded handoff. Device timestamps are
converted once, here, to the host monotonic clock (`clock.DeviceClock`). A live camera that is unplugged
or stalls is reopened with exponential backoff; a recording plays once, as fast as it is consumed.
The D435i reports its IMU in the depth camera's optical axes (x right, y down, z forward, librealsense's
convention); with `imu_to_base` (R_base_camera of the mount) the driver turns the samples into
base_link axes once, here, as the filter expects them.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Callable
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from gprbot.backoff import Backoff
from gprbot.config import RealsenseConfig
from gprbot.drivers.health import DriverHealth, HealthTracker
from gprbot.drivers.realsense.clock import DeviceClock
from gprbot.drivers.realsense.handoff import Handoff
from gprbot.drivers.realsense.readings import MotionReading, Reading, RgbdReading, Sink, SourceEvent
from gprbot.drivers.realsense.source import RealsenseSource
from gprbot.errors import DriverError
from gprbot.messages import ImuSample, RawRgbdFrame

__all__ = [
    "STREAMS", "FrameSource", "Handoff", "Message", "RealsenseDriver", "SourceFactory",
]

STREAMS = ("gyro", "accel", "depth", "color")


Message = ImuSample | RawRgbdFrame


class FrameSource(Protocol):
    """What the driver needs of a source (RealsenseSource, or a stand-in in tests)."""

    is_playback: bool
    streams: tuple[str, ...]
    device_info: dict[str, str]

    def open(self) -> None:
        """Start streaming into the sink (blocking); DriverError if the device or file is unusable."""

    def close(self) -> None:
        """Stop streaming (blocking); no sink call follows its return."""

    def wait_finished(self, timeout_s: float | None = None) -> bool:
        """Block until a recording has played to its end or the source is closed."""


SourceFactory = Callable[[RealsenseConfig, Sink, Callable[[], float]], FrameSource]

_END = object()


class RealsenseDriver:
    """The D435i (or a recording of one): `await start()`, `async for msg in driver`, `health()`, `stop()`."""

    def __init__(
        self,
        cfg: RealsenseConfig,
        clock: Callable[[], float] = time.monotonic,
        *,
        queue_size: int = 4096,  # readings: live, 6 s of IMU at 650 Hz before one is lost to a stalled loop
        frame_queue_size: int = 4,  # RGB-D frames among them, live (the oldest gives way)
        stall_timeout_s: float | None = None,  # None: realsense.stall_timeout_s (and so for the next three)
        backoff_initial_s: float | None = None,
        backoff_max_s: float | None = None,
        jump_threshold_s: float | None = None,
        source_factory: SourceFactory = RealsenseSource,
        imu_to_base: NDArray[np.float64] | None = None,
    ):
        self.cfg, self._clock, self._factory = cfg, clock, source_factory
        self.queue_size = queue_size
        self.stall_timeout_s = cfg.stall_timeout_s if stall_timeout_s is None else stall_timeout_s
        self.frame_queue_size = frame_queue_size
        first, longest = cfg.reconnect_backoff_s
        self.backoff_initial_s = first if backoff_initial_s is None else backoff_initial_s
        self.backoff_max_s = longest if backoff_max_s is None else backoff_max_s
        self.jump_threshold_s = cfg.clock_jump_threshold_s if jump_threshold_s is None else jump_threshold_s
        self._imu_to_base = None if imu_to_base is None else np.asarray(imu_to_base, dtype=np.float64)
        self.reconnects = 0
        self._session = 0  # bumped when a source is given up: readings of older sources are stale
        self._playback = cfg.playback is not None
        self._trackers = {name: HealthTracker(f"realsense.{name}") for name in STREAMS}
        self._clocks: dict[str, DeviceClock] = {}
        self._last_numbers: dict[str, int] = {}
        self._source: FrameSource | None = None
        self._handoff: Handoff | None = None
        self._out: asyncio.Queue[object] = asyncio.Queue(maxsize=16)
        self._tasks: list[asyncio.Task[None]] = []

    @property
    def device_info(self) -> dict[str, str]:
        """Name, serial, firmware and source of the camera or recording (for the run log's header)."""
        return dict(self._source.device_info) if self._source else {}

    @property
    def clock_jumps(self) -> int:
        """Device clock jumps detected so far (each re-anchored the conversion)."""
        return sum(len(c.jumps) for c in self._clocks.values())

    async def start(self) -> None:
        """Open the camera or recording; raises DriverError saying what to check if it cannot."""
        if self._handoff is not None:
            raise DriverError("the RealSense driver is already started")
        self._handoff = Handoff(asyncio.get_running_loop(), self.queue_size, block=self._playback,
                                max_frames=self.frame_queue_size)
        try:
            await self._open_source()
        except BaseException:
            self._handoff = None
            raise
        self._tasks = [asyncio.create_task(self._pump(), name="realsense-pump")]
        if self._playback:
            self._tasks.append(asyncio.create_task(self._finish_playback(), name="realsense-playback"))

    async def close(self) -> None:
        """Stop streaming and end the message iteration (messages still queued are discarded)."""
        if self._handoff is not None:
            self._handoff.close()  # first: sensor.stop() waits for callbacks blocked on a full handoff
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._tasks = []
        if self._source is not None:
            await asyncio.to_thread(self._source.close)
        for tracker in self._trackers.values():
            tracker.connected = False
        while not self._out.empty():
            self._out.get_nowait()
        self._out.put_nowait(_END)

    async def __aenter__(self) -> RealsenseDriver:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    def __aiter__(self) -> AsyncIterator[Message]:
        return self.messages()

    async def messages(self) -> AsyncIterator[Message]:
        """ImuSample (gyro-only or accel-only) and RawRgbdFrame messages in arrival order, until stopped
        or the recording ends."""
        while True:
            item = await self._out.get()
            if item is _END:
                self._out.put_nowait(_END)  # later iterations end too
                return
            assert isinstance(item, ImuSample | RawRgbdFrame)
            yield item

    def streams(self) -> dict[str, DriverHealth]:
        """Per stream (gyro, accel, depth, color): connected, rate, drops from frame-number gaps, errors."""
        return {name: tracker.snapshot() for name, tracker in self._trackers.items()}

    def health(self) -> DriverHealth:
        """The camera as one link: connected while every stream is, its IMU rate, drops and errors summed."""
        streams = list(self.streams().values())
        last = [h.last_message_t for h in streams if h.last_message_t is not None]
        errors = [h for h in streams if h.last_error]
        return DriverHealth(
            name="realsense", connected=all(h.connected for h in streams),
            rate_hz=sum(h.rate_hz for h in streams if h.name in ("realsense.gyro", "realsense.accel")),
            drops=sum(h.drops for h in streams), errors=sum(h.errors for h in streams),
            last_error=errors[-1].last_error if errors else None, last_message_t=max(last) if last else None)

    async def _open_source(self) -> None:
        assert self._handoff is not None
        handoff, session = self._handoff, self._session

        def sink(reading: Reading) -> None:
            if session == self._session:
                handoff.put(reading, force=isinstance(reading, SourceEvent))

        source = self._factory(self.cfg, sink, self._clock)
        self._source = source
        await asyncio.to_thread(source.open)
        self._clocks.clear()  # a reopened device restarts its clock and frame numbers
        self._last_numbers.clear()
        for name, tracker in self._trackers.items():
            tracker.connected = name in source.streams
            if name not in source.streams:
                tracker.error(f"no {name} stream in {source.device_info.get('source', 'the source')}")

    async def _pump(self) -> None:
        handoff = self._handoff
        assert handoff is not None
        while True:
            batch = handoff.take_all()  # in batches: one wake-up per burst, not per reading
            if not batch:
                if handoff.closed:
                    break
                try:
                    async with asyncio.timeout(None if self._playback else self.stall_timeout_s):
                        await handoff.wait()
                except TimeoutError:
                    await self._reconnect(f"no frames for {self.stall_timeout_s} s")
                continue
            for item in batch:
                if isinstance(item, SourceEvent) and item.kind == "lost":
                    await self._reconnect(item.detail)
                    break  # the rest of the batch came from the lost device
                if isinstance(item, SourceEvent):
                    self._error_all(item.detail)
                else:
                    await self._out.put(self._convert(item))
        await self._out.put(_END)

    async def _finish_playback(self) -> None:
        assert self._source is not None and self._handoff is not None
        await asyncio.to_thread(self._source.wait_finished)
        await asyncio.to_thread(self._source.close)  # returns once every callback has delivered
        self._handoff.close()
        for tracker in self._trackers.values():
            tracker.connected = False  # the recording has ended

    async def _reconnect(self, reason: str) -> None:
        self._session += 1
        self._error_all(f"device lost: {reason}; reconnecting")
        for tracker in self._trackers.values():
            tracker.connected = False
        if self._source is not None:
            await asyncio.to_thread(self._source.close)
        backoff = Backoff(self.backoff_initial_s, self.backoff_max_s)
        while True:
            await asyncio.sleep(backoff.next_s())
            try:
                await self._open_source()
            except DriverError as exc:
                self._error_all(str(exc))
                continue
            self.reconnects += 1
            return

    def _convert(self, reading: MotionReading | RgbdReading) -> Message:
        clock = self._clocks.get(reading.domain)
        if clock is None:
            clock = DeviceClock(follow_host=not self._playback, jump_threshold_s=self.jump_threshold_s)
            self._clocks[reading.domain] = clock
        jumps = len(clock.jumps)
        if isinstance(reading, MotionReading):
            t = clock.to_host(reading.device_ms, reading.host_s, reading.stream)
            self._count(reading.stream, reading.number, t)
            xyz = reading.xyz if self._imu_to_base is None else self._imu_to_base @ reading.xyz
            message: Message = ImuSample(t=t, gyro=xyz) if reading.stream == "gyro" else ImuSample(t=t, accel=xyz)
        else:
            t = clock.to_host(reading.device_ms, reading.host_s, "rgbd")
            self._count("depth", reading.depth_number, t)
            self._count("color", reading.color_number, t)
            fx, fy, cx, cy = reading.intrinsics
            message = RawRgbdFrame(
                t, reading.depth_number, reading.color, reading.depth, reading.depth_scale, fx, fy, cx, cy
            )
        for jump in clock.jumps[jumps:]:
            self._error_all(f"device clock ({reading.domain}) jumped by {jump.offset_change_s:+.3f} s at "
                            f"{jump.stream} t={jump.device_s:.3f} s; re-anchored")
        return message

    def _count(self, stream: str, number: int, t: float) -> None:
        tracker = self._trackers[stream]
        last = self._last_numbers.get(stream)
        if last is not None and number > last + 1:
            tracker.dropped(number - last - 1)
        self._last_numbers[stream] = number
        tracker.message(t)

    def _error_all(self, text: str) -> None:
        for name, tracker in self._trackers.items():
            if self._source is None or name in self._source.streams:
                tracker.error(text)
