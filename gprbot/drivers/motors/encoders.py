"""Wheel encoder readings as published by the motor driver, and the 32-bit count unwrapper.

Pure (no I/O), so that odometry and replay can import it without the serial driver.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.messages import WheelSpeeds, register_message


@dataclass(frozen=True)
class WheelEncoders:
    """Wheel encoder readings: counts (int64, unwrapped past the 32-bit wrap) and speeds (rad/s).

    `speed_spread_s`: how far apart the three speed requests left (0 in logs from before it existed).
    The filter takes the three speeds as one instant; on a busy loop they are not, and while the wheels
    speed up or stop their mixture reads as a motion the base did not make (see the issue 14 note).
    """

    t: float
    counts: NDArray[np.int64]
    speeds: NDArray[np.float64]
    speed_spread_s: float = 0.0

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
