"""The one driver contract: `start()`, `close()`, `health()` → DriverHealth, and the reconnect backoff.

Every device driver (motors, GPR, RealSense) satisfies `Driver`, so the runtime starts, closes and
reports them alike; `status` reads `health()` (and, for a driver with several streams, `streams()`).
`Backoff` is the one exponential backoff of the reconnect loops: waits from `first_s` doubling to
`longest_s`, back to the first after a success.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol

from gprbot.drivers.health import DriverHealth


class LinkState(enum.Enum):
    """Where a device link stands, as `status` names it."""

    UP = "connected"
    DOWN = "DISCONNECTED"  # reconnecting, or not (yet) started


def link_state(health: DriverHealth) -> LinkState:
    """The link state a health snapshot says."""
    return LinkState.UP if health.connected else LinkState.DOWN


class Driver(Protocol):
    """What the runtime needs of every device driver."""

    async def start(self) -> None: ...

    async def close(self) -> None: ...

    def health(self) -> DriverHealth: ...


class MultiStreamDriver(Driver, Protocol):
    """A driver with several streams (the RealSense: gyro, accel, depth, colour), each with its health."""

    def streams(self) -> Mapping[str, DriverHealth]: ...


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
