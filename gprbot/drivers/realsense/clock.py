"""Time on the RealSense: the device clock (milliseconds) converted to host monotonic seconds with jump
detection, and depth/colour frames paired by their timestamps.

Pure: the host receive time of each sample is passed in, the clock is never read here. One `DeviceClock`
serves every stream of one timestamp domain (hardware clock, global time, system time), so that gyro,
accel, depth and colour samples taken at the same instant get the same host time.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Generic, TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class ClockJump:
    """A detected discontinuity of the device clock: where it happened and how far the offset moved."""

    stream: str
    device_s: float
    offset_change_s: float


class DeviceClock:
    """Maps device timestamps to host time as `host = device + offset`, the offset estimated once per sample.

    Live (`follow_host=True`): host receive time minus device time is the true offset plus a transport
    delay >= 0, so the minimum over a sliding window of `window_s` host seconds is the offset estimate
    (the minimum-delay filter); the window lets the estimate follow crystal drift (~50 ppm on a D435i).
    Playback (`follow_host=False`): a recording plays faster than real time, so receive times mean
    nothing; the offset is anchored on the first sample and kept, which preserves the recorded spacing.

    A jump is a stream's device time going backwards by more than `jump_threshold_s` (device reset, USB
    re-enumeration) or, live, the filtered offset moving by more than `jump_threshold_s` (the device
    clock leapt ahead, or ran slow for a whole window). Each re-anchors the offset and is counted.
    """

    def __init__(self, *, follow_host: bool = True, jump_threshold_s: float = 0.1, window_s: float = 10.0):
        self.follow_host = follow_host
        self.jump_threshold_s = jump_threshold_s
        self.window_s = window_s
        self.jumps: list[ClockJump] = []
        self._offset: float | None = None
        self._last_device_s: dict[str, float] = {}
        self._last_host_t = float("-inf")
        self._window: deque[tuple[float, float]] = deque()  # (receive time, observed offset), offsets rising

    @property
    def offset_s(self) -> float | None:
        """The current offset (host minus device seconds); None before the first sample."""
        return self._offset

    def to_host(self, device_ms: float, host_receive_s: float, stream: str = "") -> float:
        """Host monotonic time of a sample stamped `device_ms` on `stream`, received at `host_receive_s`."""
        device_s = device_ms / 1000.0
        observed = host_receive_s - device_s
        last = self._last_device_s.get(stream)
        self._last_device_s[stream] = device_s
        if self._offset is None:
            self._anchor(observed, host_receive_s)
        elif last is not None and device_s < last - self.jump_threshold_s:
            anchor = observed if self.follow_host else max(host_receive_s, self._last_host_t) - device_s
            self._jump(stream, device_s, anchor, host_receive_s)
        elif self.follow_host:
            estimate = self._filtered(observed, host_receive_s)
            if abs(estimate - self._offset) > self.jump_threshold_s:
                self._jump(stream, device_s, observed, host_receive_s)
            else:
                self._offset = estimate
        assert self._offset is not None
        host_t = device_s + self._offset
        self._last_host_t = max(self._last_host_t, host_t)
        return host_t

    def reset(self) -> None:
        """Forget the offset (a new device session): the next sample anchors afresh, no jump counted."""
        self._offset = None
        self._last_device_s.clear()
        self._window.clear()

    def _filtered(self, observed: float, host_receive_s: float) -> float:
        window = self._window
        while window and window[-1][1] >= observed:
            window.pop()
        window.append((host_receive_s, observed))
        while window[0][0] < host_receive_s - self.window_s:
            window.popleft()
        return window[0][1]

    def _anchor(self, offset: float, host_receive_s: float) -> None:
        self._offset = offset
        self._window.clear()
        self._window.append((host_receive_s, offset))

    def _jump(self, stream: str, device_s: float, offset: float, host_receive_s: float) -> None:
        assert self._offset is not None
        self.jumps.append(ClockJump(stream, device_s, offset - self._offset))
        self._anchor(offset, host_receive_s)
        # A reset makes every stream's history stale, not only the one that revealed it.
        self._last_device_s = {stream: device_s}


@dataclass
class FramePairer(Generic[T]):
    """Pairs depth with colour frames whose timestamps lie within `tolerance_ms`; an unpaired frame is
    superseded by the next of its stream (the frame-number gap then shows it as a drop)."""

    tolerance_ms: float
    _pending: dict[str, tuple[float, T]] = field(default_factory=dict)

    def offer(self, stream: str, timestamp_ms: float, item: T) -> tuple[T, T] | None:
        """Add a "depth" or "color" frame; returns (depth, colour) when it completes a pair."""
        other = "color" if stream == "depth" else "depth"
        waiting = self._pending.get(other)
        if waiting is not None and abs(waiting[0] - timestamp_ms) <= self.tolerance_ms:
            del self._pending[other]
            return (item, waiting[1]) if stream == "depth" else (waiting[1], item)
        self._pending[stream] = (timestamp_ms, item)
        if waiting is not None and waiting[0] < timestamp_ms - self.tolerance_ms:
            del self._pending[other]  # too old to match anything still to come
        return None
