"""A speed-controlled motor for the emulator: an optional acceleration ramp, then a first-order lag.

The setpoint ramps linearly at `accel` (counts/s²) towards the target (or jumps, for the "as fast as
possible" commands); the shaft speed follows the setpoint with time constant tau. Both are solved in
closed form per segment, so encoder counts are exact at any query time, however sparse the queries.
"""

from __future__ import annotations

import math


class LaggedMotor:
    """One motor channel; speeds in encoder counts per second, position in counts."""

    def __init__(self, time_constant_s: float, t: float) -> None:
        if time_constant_s <= 0:
            raise ValueError(f"motor time constant must be > 0 s, got {time_constant_s}")
        self.tau = time_constant_s
        self.t = t
        self.position = 0.0
        self.speed = 0.0
        self.setpoint = 0.0
        self.target = 0.0
        self.accel: float | None = None

    def command(self, t: float, target: float, accel: float | None = None) -> None:
        """Set a new target speed at time t; `accel` None jumps the setpoint, else ramps it."""
        self.advance(t)
        self.target = float(target)
        self.accel = accel if accel is not None and accel > 0 else None
        if self.accel is None:
            self.setpoint = self.target

    def advance(self, t: float) -> None:
        """Integrate speed and position up to time t (no-op if t is not later than the state)."""
        while t > self.t:
            slope = 0.0
            end = t
            if self.accel is not None and self.setpoint != self.target:
                slope = math.copysign(self.accel, self.target - self.setpoint)
                end = min(t, self.t + abs(self.target - self.setpoint) / self.accel)
            self._segment(end - self.t, slope)
            self.t = end
            if slope and end < t:
                self.setpoint = self.target  # ramp finished inside this interval

    def _segment(self, dt: float, slope: float) -> None:
        # v' = (s(t) - v) / tau with s(t) = s0 + slope t has the solution
        # v(t) = s(t) - slope tau + (v0 - s0 + slope tau) e^(-t/tau).
        tau, s0 = self.tau, self.setpoint
        decay = math.exp(-dt / tau)
        c = self.speed - s0 + slope * tau
        self.position += s0 * dt + 0.5 * slope * dt * dt - slope * tau * dt + c * tau * (1.0 - decay)
        self.speed = s0 + slope * dt - slope * tau + c * decay
        new_setpoint = s0 + slope * dt
        if slope:
            passed = (new_setpoint - self.target) * slope >= 0
            self.setpoint = self.target if passed else new_setpoint
