"""Jog commands with a deadman: move at (vx, vy) for a while, but only while the operator keeps feeding.

The controller is pure: every call takes `now` (host monotonic seconds). It yields a body velocity
(vx, vy) only — the robot never rotates; heading hold adds ω downstream (`HeadingHoldDrive`).
"""

from __future__ import annotations

import math
from enum import Enum

import numpy as np

from gprbot.errors import GprbotError
from gprbot.motion.kinematics import FloatArray


class JogError(GprbotError):
    """A jog command is not usable (not finite, negative duration); the message says what to send."""


class JogStop(Enum):
    """Why the last jog ended."""

    DURATION = "duration"
    DEADMAN = "deadman"
    STOPPED = "stopped"
    REPLACED = "replaced"


class JogController:
    """Holds the current jog; `update(now)` gives the body velocity to apply, zero once it has ended.

    A jog ends when its duration has run out (at start + duration, exclusive), when no `feed` came for
    `deadman_timeout_s` (the jog command itself counts as the first feed), or on `stop`. An ended jog
    stays ended: a late feed does not revive it.
    """

    def __init__(
        self, max_speed_m_s: float = 0.3, deadman_timeout_s: float = 0.5, max_duration_s: float = 60.0
    ) -> None:
        for name, value in (
            ("max_speed_m_s", max_speed_m_s),
            ("deadman_timeout_s", deadman_timeout_s),
            ("max_duration_s", max_duration_s),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"JogController {name} must be a positive finite number, got {value!r}")
        self.max_speed_m_s = max_speed_m_s
        self.deadman_timeout_s = deadman_timeout_s
        self.max_duration_s = max_duration_s
        self._velocity: FloatArray = np.zeros(2)
        self._end_t = -math.inf
        self._last_feed_t = -math.inf
        self._active = False
        self.last_stop: JogStop | None = None

    @property
    def active(self) -> bool:
        """Whether a jog is running (as of the last call; `update` is what ends it on time)."""
        return self._active

    def jog(self, vx: float, vy: float, duration_s: float, now: float) -> FloatArray:
        """Start a jog at body velocity (vx, vy) m/s for duration_s; the velocity actually granted.

        A speed above max_speed_m_s is scaled down keeping its direction; a duration above
        max_duration_s is cut to it. A jog while another runs replaces it.
        """
        if not all(math.isfinite(v) for v in (vx, vy, duration_s, now)):
            raise JogError(f"jog needs finite numbers: vx={vx!r} vy={vy!r} duration={duration_s!r}")
        if duration_s < 0.0:
            raise JogError(f"jog duration must be ≥ 0 s, got {duration_s}; use stop to halt")
        velocity = np.array([vx, vy], dtype=np.float64)
        speed = float(np.hypot(vx, vy))
        if speed > self.max_speed_m_s:
            velocity *= self.max_speed_m_s / speed
        self._expire(now)
        if self._active:
            self.last_stop = JogStop.REPLACED
        self._velocity = velocity
        self._end_t = now + min(duration_s, self.max_duration_s)
        self._last_feed_t = now
        self._active = True
        return velocity.copy()

    def feed(self, now: float) -> bool:
        """Keep the deadman alive; whether a jog is still running (a lapsed jog is not revived)."""
        self._expire(now)
        if self._active:
            self._last_feed_t = max(self._last_feed_t, now)
        return self._active

    keepalive = feed

    def stop(self, now: float) -> FloatArray:
        """End the jog immediately; the zero velocity to apply."""
        del now  # kept for a uniform, time-stamped API
        if self._active:
            self.last_stop = JogStop.STOPPED
        self._active = False
        self._velocity = np.zeros(2)
        return np.zeros(2)

    def update(self, now: float) -> FloatArray:
        """The body velocity (vx, vy) m/s to apply at time now."""
        self._expire(now)
        return self._velocity.copy() if self._active else np.zeros(2)

    def _expire(self, now: float) -> None:
        """End the jog if its duration or the deadman ran out by `now`, recording which came first."""
        if not self._active:
            return
        deadman_t = self._last_feed_t + self.deadman_timeout_s
        if now >= min(deadman_t, self._end_t):
            self._active = False
            self._velocity = np.zeros(2)
            self.last_stop = JogStop.DURATION if self._end_t <= deadman_t else JogStop.DEADMAN
