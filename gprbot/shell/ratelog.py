"""Log lines that a client can trigger at will, rate-limited so a flood cannot fill (or trip) journald."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable


class RateLimitedLog:
    """At most `burst` lines per `key` every `period_s`; the next line admitted says how many were held back."""

    def __init__(self, logger: logging.Logger, period_s: float = 10.0, burst: int = 3,
                 clock: Callable[[], float] = time.monotonic, max_keys: int = 1024) -> None:
        self._log, self.period_s, self.burst, self._clock, self._max_keys = logger, period_s, burst, clock, max_keys
        self._windows: dict[str, tuple[float, int, int]] = {}  # key → (window start, lines, held back)
        self.suppressed = 0

    def log(self, level: int, key: str, message: str, *args: object) -> None:
        """Log `message % args` at `level` unless `key` has used up its lines in this window."""
        now = self._clock()
        if key not in self._windows and len(self._windows) >= self._max_keys:
            self._windows = {k: w for k, w in self._windows.items() if now - w[0] < self.period_s}
            if len(self._windows) >= self._max_keys:
                key = "(many keys)"  # bounded memory: a flood of new keys shares one window
        start, lines, held = self._windows.get(key, (now, 0, 0))
        if now - start >= self.period_s:
            start, lines = now, 0
        if lines >= self.burst:
            self._windows[key] = (start, lines, held + 1)
            self.suppressed += 1
            return
        self._windows[key] = (start, lines + 1, 0)
        if held:
            message += f" ({held} similar lines held back in the last {self.period_s:g} s)"
        self._log.log(level, message, *args)
