"""Driver health as published to the daemon's `status`: connected, rate, drops, last error."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

SLOW_FRACTION = 0.5  # a stream below half its registered rate is reported SLOW by `status`


@dataclass(frozen=True)
class DriverHealth:
    """A snapshot of one driver's health."""

    name: str
    connected: bool
    rate_hz: float
    drops: int
    errors: int
    last_error: str | None
    last_message_t: float | None

    def slow_against(self, expected_hz: float | None) -> bool:
        """Whether a connected, flowing stream runs under SLOW_FRACTION of its expected rate."""
        return (expected_hz is not None and self.connected and self.last_message_t is not None
                and self.rate_hz < SLOW_FRACTION * expected_hz)


@dataclass
class HealthTracker:
    """Mutable counters a driver updates; `snapshot()` gives the published DriverHealth.

    Times are passed in (host monotonic seconds) so that the tracker itself never reads the clock.
    """

    name: str
    window_s: float = 2.0
    connected: bool = False
    drops: int = 0
    errors: int = 0
    last_error: str | None = None
    _stamps: deque[float] = field(default_factory=deque)

    def message(self, t: float) -> None:
        """Count one received message at host time t."""
        self._stamps.append(t)
        while self._stamps and self._stamps[0] < t - self.window_s:
            self._stamps.popleft()

    def error(self, text: str) -> None:
        """Record an error (kept as the last error)."""
        self.errors += 1
        self.last_error = text

    def dropped(self, count: int = 1) -> None:
        """Record messages known to be lost (e.g. missed trace numbers)."""
        self.drops += count

    def snapshot(self) -> DriverHealth:
        """The current health as an immutable message."""
        stamps = self._stamps
        span = stamps[-1] - stamps[0] if len(stamps) > 1 else 0.0
        rate = (len(stamps) - 1) / span if span > 0 else 0.0
        return DriverHealth(
            name=self.name,
            connected=self.connected,
            rate_hz=rate,
            drops=self.drops,
            errors=self.errors,
            last_error=self.last_error,
            last_message_t=stamps[-1] if stamps else None,
        )
