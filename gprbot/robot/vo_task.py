"""Visual odometry in the daemon: RGB-D frames from the RealSense driver through RgbdOdometry in a thread.

The event loop hands each frame to `offer` (never blocks): a bounded queue that drops the oldest
frame when VO falls behind, and counts it. The thread runs the pure `fusion.vo` stage (OpenCV releases
the GIL for the heavy parts) and hands each measurement back to the loop with `call_soon_threadsafe`,
stamped with its frame's capture time, so it reaches the filter through the reorder window like any
late sensor message. `health()` is what `status` and the run log report: tracked features, inlier
ratio, frame rate, latency (capture to measurement), drops and the thread's own CPU time.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable

import cv2
import numpy as np

from gprbot.fusion.vo import RgbdOdometry
from gprbot.fusion.vo_geometry import VoConfig
from gprbot.fusion.vo_map import MapConfig
from gprbot.geometry import CameraMount
from gprbot.messages import RawRgbdFrame, RgbdFrame, VoHealth, VoMeasurement

log = logging.getLogger(__name__)
WINDOW = 60  # frames over which rate and latency are reported (2 s at 30 fps)


def to_metric(frame: RawRgbdFrame) -> RgbdFrame:
    """The driver's frame (depth in device units) as the VO's (depth in metres)."""
    depth = frame.depth.astype(np.float32) * np.float32(frame.depth_scale)
    return RgbdFrame(frame.t, frame.color, depth, frame.fx, frame.fy, frame.cx, frame.cy)


class VoTask:
    """RgbdOdometry behind a drop-oldest queue, in its own thread; measurements delivered on the loop."""

    def __init__(self, mount: CameraMount, deliver: Callable[[VoMeasurement], None], *, queue_size: int = 2,
                 config: VoConfig | None = None, map_slots: int = MapConfig.slots,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.odometry = RgbdOdometry(mount, config, MapConfig(slots=map_slots))
        self._deliver, self._clock = deliver, clock
        self._queue: deque[RawRgbdFrame] = deque(maxlen=queue_size)
        self._ready = threading.Condition()
        self._stop = False
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self.dropped = 0
        self.measurements = 0
        self._done_t: deque[float] = deque(maxlen=WINDOW)
        self._latency: deque[float] = deque(maxlen=WINDOW)
        self._cpu_s = 0.0

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Start the VO thread; measurements go to `deliver` on `loop`."""
        # One thread for OpenCV, process-wide: its worker pool would compete with the control loop for
        # the NUC's cores, and VO's cost would hide outside the VO thread's CPU time that `health` reports.
        cv2.setNumThreads(1)
        self._loop, self._stop = loop, False
        self._thread = threading.Thread(target=self._run, name="vo", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread (the frame in progress finishes; queued frames are discarded)."""
        with self._ready:
            self._stop = True
            self._ready.notify()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    @property
    def native_id(self) -> int | None:
        """The VO thread's OS id (for per-thread CPU accounting)."""
        return self._thread.native_id if self._thread is not None else None

    def offer(self, frame: RawRgbdFrame) -> None:
        """Queue a frame for VO (from the event loop; never blocks); the oldest is dropped when full."""
        with self._ready:
            if len(self._queue) == self._queue.maxlen:
                self.dropped += 1
            self._queue.append(frame)
            self._ready.notify()

    def health(self) -> VoHealth:
        """Counts, the last frame's tracking quality, rate and latency over the last WINDOW frames."""
        vo = self.odometry
        estimate, keyframe = vo.last_estimate, vo.keyframe
        done, latency = list(self._done_t), np.array(self._latency)
        rate = (len(done) - 1) / (done[-1] - done[0]) if len(done) > 1 and done[-1] > done[0] else 0.0
        tracked = estimate.tracked if estimate is not None else 0
        state = "starting" if vo.frames == 0 else "tracking" if keyframe is not None else "lost"
        return VoHealth(
            self._clock(), state, vo.frames, self.dropped, vo.lost_frames, self.measurements,
            len(keyframe.points_2d) if keyframe is not None else 0, tracked,
            estimate.inliers / tracked if estimate is not None and tracked else 0.0, rate,
            float(np.median(latency)) * 1e3 if latency.size else 0.0,
            float(latency.max()) * 1e3 if latency.size else 0.0, self._cpu_s, vo.last_failure,
            len(vo.map.entries), vo.map.attempts, vo.map.found,
        )

    def _run(self) -> None:
        while True:
            with self._ready:
                while not self._queue and not self._stop:
                    self._ready.wait()
                if self._stop:
                    return
                frame = self._queue.popleft()
            began = time.thread_time()
            try:
                measurements = self.odometry.process(to_metric(frame))
            except Exception:  # a bad frame must not end VO; the filter carries on without it
                log.exception("visual odometry failed on frame %d", frame.number)
                measurements = []
            self._cpu_s += time.thread_time() - began
            now = self._clock()
            self._done_t.append(now)
            self._latency.append(now - frame.t)
            self.measurements += len(measurements)
            if measurements and self._loop is not None:
                with contextlib.suppress(RuntimeError):  # the loop is closed: the daemon is exiting
                    self._loop.call_soon_threadsafe(self._hand_over, measurements)

    def _hand_over(self, measurements: list[VoMeasurement]) -> None:
        for measurement in measurements:
            self._deliver(measurement)
