"""Wheel encoder readings as published by the motor driver, and the 32-bit count unwrapper.

Pure (no I/O), so that odometry and replay can import it without the serial driver.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.messages import WheelSpeeds, register_message

# The three speeds of a reading must describe one encoder poll (20 ms) to be one twist of the base: read
# further apart on a busy loop, while the wheels speed up or stop, they mix instants and the filter
# took their mixture for a sideways motion (a 4 cm/s phantom vy, 16 cm off in 3 s).
MAX_SPEED_SPREAD_S = 0.02


@dataclass(frozen=True)
class WheelEncoders:
    """Wheel encoder readings: counts (int64, unwrapped past the 32-bit wrap) and speeds (rad/s).

    `speed_spread_s`: how far apart the three speed requests left (0 in logs from before it existed).
    """

    t: float
    counts: NDArray[np.int64]
    speeds: NDArray[np.float64]
    speed_spread_s: float = 0.0

    @property
    def coherent(self) -> bool:
        """Whether the speeds describe one instant (the filter's wheel update takes only those)."""
        return self.speed_spread_s <= MAX_SPEED_SPREAD_S

    def wheel_speeds(self) -> WheelSpeeds:
        """The measured speeds as the WheelSpeeds message that wheel odometry consumes."""
        return WheelSpeeds(t=self.t, speeds=self.speeds.copy())


register_message(WheelEncoders)


class CountUnwrapper:
    """Turns the controller's wrapping 32-bit count into a continuous count, across reconnects too."""

    def __init__(self) -> None:
        self.value: int | None = None
        self._last_raw: int | None = None

    def update(self, raw: int) -> int:
        """The continuous count for a new raw 32-bit reading (the first reading is read as signed)."""
        if self.value is None:
            self.value = raw - 2**32 if raw >= 2**31 else raw
        elif self._last_raw is not None:
            self.value += (raw - self._last_raw + 2**31) % 2**32 - 2**31
        self._last_raw = raw
        return self.value

    def rebase(self, raw: int | None = None) -> None:
        """Forget the last raw count (after a reconnect the next reading continues from `value`)."""
        self._last_raw = raw
