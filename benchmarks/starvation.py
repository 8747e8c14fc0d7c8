"""A deterministic starver: holds the GIL for `block_s` every `period_s`, from a thread of its own.

What a loaded machine does to the daemon, made repeatable: while another thread holds the GIL (a
long C call, a descheduled process), the event loop and every thread of the process stand still,
and the timers and readers behind them all fire at once afterwards — at whatever point the loop was,
e.g. between writing a request and reading its reply. libc's `usleep` called through `ctypes.PyDLL`
keeps the GIL for exactly the given time (PyDLL never releases it). Used by the starvation tests and
benchmarks to show that results and safety do not depend on the machine's load.
"""

from __future__ import annotations

import ctypes
import threading
import time
from types import TracebackType

_LIBC = ctypes.PyDLL(None)  # PyDLL: the GIL stays held during the call, which is the point


class GilStarver:
    """`with GilStarver(0.06, 0.2):` stops the whole process's Python for 60 ms in every 200 ms."""

    def __init__(self, block_s: float, period_s: float) -> None:
        if not 0.0 < block_s < period_s:
            raise ValueError(f"need 0 < block_s < period_s, got block {block_s} s, period {period_s} s")
        self.block_s = block_s
        self.period_s = period_s
        self.blocks = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _run(self) -> None:
        next_t = time.monotonic() + self.period_s
        while not self._stop.wait(max(0.0, next_t - time.monotonic())):
            _LIBC.usleep(round(self.block_s * 1e6))
            self.blocks += 1
            next_t += self.period_s

    def __enter__(self) -> GilStarver:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="gil-starver", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
