"""The bounded, thread-safe handoff of readings from librealsense's threads to the asyncio event loop."""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections import deque

from gprbot.drivers.realsense.readings import Reading, RgbdReading


class Handoff:
    """A bounded FIFO from SDK threads to the event loop. When full, a producer waits (`block`: a
    recording, whose playback this slows down) or its reading is dropped (a live camera must not stall).

    Live, RGB-D frames have a bound of their own (`max_frames`, the oldest queued frame gives way: VO
    wants the newest) so that a stalled loop costs stale frames, never IMU samples: `maxsize` is then
    sized for seconds of IMU (a frame is 100–1000× the bytes of a sample).
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, maxsize: int, block: bool, max_frames: int | None = None):
        self._loop, self._maxsize, self._block = loop, maxsize, block
        self._max_frames = max_frames
        self._frames = 0
        self.frames_dropped = 0  # live frames given up for newer ones
        self._items: deque[Reading] = deque()
        self._lock = threading.Lock()
        self._not_full = threading.Condition(self._lock)
        self._ready = asyncio.Event()
        self._closed = False

    def put(self, item: Reading, force: bool = False) -> bool:
        """Queue a reading from any thread; False if dropped (full and not blocking, or closed)."""
        with self._not_full:
            while not force and self._block and len(self._items) >= self._maxsize and not self._closed:
                self._not_full.wait()
            if self._closed or (not force and len(self._items) >= self._maxsize):
                return False
            if isinstance(item, RgbdReading):
                if not self._block and self._max_frames is not None and self._frames >= self._max_frames:
                    oldest = next(i for i, queued in enumerate(self._items) if isinstance(queued, RgbdReading))
                    del self._items[oldest]
                    self._frames -= 1
                    self.frames_dropped += 1
                self._frames += 1
            was_empty = not self._items
            self._items.append(item)
        if was_empty:
            self._wake()
        return True

    def take_all(self) -> list[Reading]:
        """Every reading queued now, oldest first (empty if none); waiting producers resume."""
        with self._lock:
            items = list(self._items)
            self._items.clear()
            self._frames = 0
            self._not_full.notify_all()
            if not items and not self._closed:
                self._ready.clear()  # under the lock: a put after this sets it again
        return items

    @property
    def closed(self) -> bool:
        """True once `close` was called (readings may still be queued)."""
        return self._closed

    async def wait(self) -> None:
        """Return when readings are queued or the handoff is closed."""
        await self._ready.wait()

    def close(self) -> None:
        """No more readings: waiting producers return; what is queued can still be taken."""
        with self._lock:
            self._closed = True
            self._not_full.notify_all()
        self._wake()

    def _wake(self) -> None:
        with contextlib.suppress(RuntimeError):  # the loop is already closed: nobody is listening
            self._loop.call_soon_threadsafe(self._ready.set)
