"""A simulated D435i on the live driver path: an `rs.software_device` fed in real time by the simulator.

The simulated robot pushes IMU samples and rendered RGB-D frames into a `SoftwareD435i` as they
happen, stamped on a device clock of its own (the camera's boot time is not the host's), and the
daemon opens it with the same `RealsenseSource` → `RealsenseDriver` path as a camera on USB: the
sensors are opened and started by the source, librealsense calls back from its own threads, and the
driver converts the device clock and tracks health. Frames are rendered in a thread of the emulator
(not on the event loop): a frame is rendered once the simulator's truth covers its exposure.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.config import RealsenseConfig
from gprbot.drivers.realsense.readings import Intrinsics
from gprbot.drivers.realsense.recording import RecordingRates, SoftwareD435i
from gprbot.drivers.realsense.source import RealsenseSource, Sink

log = logging.getLogger(__name__)
DEVICE_BOOT_OFFSET_S = 1234.567  # the emulated camera's clock reads host time minus this (any value will do)

# (colour BGR uint8 (h, w, 3), depth uint16 in depth units (h, w)) rendered for time t, or None if not yet due
Renderer = Callable[[float], tuple[NDArray[np.uint8], NDArray[np.uint16]] | None]


class D435iEmulator:
    """The software D435i and its frame thread: `push_imu` from the simulator, frames from `renderer`."""

    def __init__(self, cfg: RealsenseConfig, intrinsics: Intrinsics, clock: Callable[[], float],
                 renderer: Renderer, serial: str = "sim-d435i") -> None:
        self.cfg, self._clock, self._renderer = cfg, clock, renderer
        self.camera = SoftwareD435i(cfg.width, cfg.height, intrinsics,
                                    RecordingRates(cfg.gyro_hz, cfg.accel_hz, cfg.fps), serial=serial)
        self.frames_pushed = 0
        self.render_cpu_s = 0.0  # the frame thread's CPU time: the simulator's cost, not the robot's
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._push_lock = threading.Lock()  # one producer at a time into librealsense

    @property
    def native_id(self) -> int | None:
        """The frame thread's OS id (for per-thread CPU accounting)."""
        return self._thread.native_id if self._thread is not None else None

    @property
    def device(self) -> Any:
        """The `rs.software_device` to open in place of a D435i."""
        return self.camera.device

    def source_factory(self, cfg: RealsenseConfig, sink: Sink, clock: Callable[[], float]) -> RealsenseSource:
        """What `RealsenseDriver(source_factory=...)` calls: the real source, opened on this device."""
        return RealsenseSource(cfg, sink, clock, device=self.device)

    def device_ms(self, t: float) -> float:
        """The emulated camera's clock (ms) at host time t."""
        return (t - DEVICE_BOOT_OFFSET_S) * 1000.0

    def push_imu(self, t: float, gyro: NDArray[np.float64] | None = None,
                 accel: NDArray[np.float64] | None = None) -> None:
        """One IMU sample taken at host time t (gyro rad/s, accel m/s², in the camera's IMU axes)."""
        with self._push_lock, contextlib.suppress(RuntimeError):  # sensors not started (yet, or any more)
            if gyro is not None:
                self.camera.push("gyro", t - DEVICE_BOOT_OFFSET_S, gyro)
            if accel is not None:
                self.camera.push("accel", t - DEVICE_BOOT_OFFSET_S, accel)

    def start(self) -> None:
        """Start the frame thread (frames at cfg.fps from now on)."""
        self._stop.clear()
        self._thread = threading.Thread(target=self._frames, name="sim-d435i-frames", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the frame thread."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def _frames(self) -> None:
        period = 1.0 / self.cfg.fps
        next_t, number = self._clock(), 0
        while not self._stop.is_set():
            began = time.thread_time()
            try:
                rendered = self._renderer(next_t)
            except Exception:  # a simulator bug must not kill the camera silently
                log.exception("the simulated camera could not render t=%.3f", next_t)
                rendered = None
            if rendered is None:  # the truth does not cover this exposure yet
                self._stop.wait(0.002)
                continue
            color, depth = rendered
            with self._push_lock, contextlib.suppress(RuntimeError):
                self.camera.push("depth", next_t - DEVICE_BOOT_OFFSET_S, depth, number)
                self.camera.push("color", next_t - DEVICE_BOOT_OFFSET_S, color, number)
                self.frames_pushed += 1
            self.render_cpu_s += time.thread_time() - began
            next_t, number = next_t + period, number + 1
            behind = int((self._clock() - next_t) / period)
            if behind > 5:  # starved of CPU: skip frames (the numbering shows the gap, as a camera's would)
                next_t, number = next_t + behind * period, number + behind
            self._stop.wait(max(0.0, next_t - self._clock()))
