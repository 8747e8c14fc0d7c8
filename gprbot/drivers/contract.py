"""The one driver contract: `start()`, `close()`, `health()` → DriverHealth, and the reconnect backoff.

Every device driver (motors, GPR, RealSense) satisfies `Driver`, so the runtime starts, closes and
reports them alike; `status` reads `health()` (and, for a driver with several streams, `streams()`).
Their reconnect loops wait with the one `gprbot.backoff.Backoff` (the supervisor's restarts too).
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
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
