"""The one exponential backoff: the drivers' reconnect loops and the supervisor's task restarts wait with it."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class Backoff:
    """Exponential waits between reconnect attempts: first_s, doubling, at most longest_s."""

    first_s: float
    longest_s: float
    _next_s: float = field(init=False)

    def __post_init__(self) -> None:
        self._next_s = self.first_s

    def next_s(self) -> float:
        """The wait before the next attempt (and double the one after)."""
        wait = self._next_s
        self._next_s = min(2.0 * wait, self.longest_s)
        return wait

    def reset(self) -> None:
        """A success: the next wait is the first again."""
        self._next_s = self.first_s
