"""The recorder: queues every raw message while a run log is open and writes it off the event loop.

Producers call `append` (cheap: a deque append). The recorder task drains the queue every `flush_s`
and hands the batch to the run log's one writer thread, so the run log's writes and periodic fsync
never stall the control loop. One thread, one write in flight, ever: a cancelled or restarted task
waits for the write already running instead of starting another, so records stay in order and the
end marker is the last record. A slow disk is reported (`last_error`), not mistaken for a hung task.
`open`/`close` bracket one run (a survey).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import time
from collections import deque
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from gprbot.errors import GprbotError
from gprbot.runlog import RunLogWriter

log = logging.getLogger(__name__)


class Recorder:
    """Owns the open RunLogWriter (if any), the queue of messages waiting and the one writer thread."""

    def __init__(self, flush_s: float = 0.05, stall_report_s: float = 2.0) -> None:
        self.flush_s = flush_s
        self.stall_report_s = stall_report_s
        self.writer: RunLogWriter | None = None
        self.run_dir: Path | None = None
        self.records = 0
        self.last_error: str | None = None
        self._queue: deque[tuple[Any, float]] = deque()
        self._lock = asyncio.Lock()
        self._thread = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="runlog-writer")
        self._inflight: asyncio.Future[None] | None = None

    @property
    def recording(self) -> bool:
        """Whether a run log is open."""
        return self.writer is not None

    @property
    def queued(self) -> int:
        """Messages waiting to be written."""
        return len(self._queue)

    def open(self, run_dir: Path, header: Mapping[str, Any]) -> None:
        """Start a run log in run_dir (header first); GprbotError if one is open already."""
        if self.writer is not None:
            raise GprbotError(f"a run log is already open in {self.run_dir}; end that run first")
        self.writer = RunLogWriter(run_dir, header)
        self.run_dir = run_dir

    def append(self, message: Any, t_received: float) -> None:
        """Queue one message for the open run log (dropped when no run is being recorded)."""
        if self.writer is not None:
            self._queue.append((message, t_received))

    async def flush(self) -> None:
        """Write everything queued so far (on the writer thread), after any write still in flight."""
        async with self._lock:
            await self._wait_inflight()
            writer = self.writer
            if writer is None or not self._queue:
                return
            batch = list(self._queue)
            self._queue.clear()
            self._submit(_write_batch, writer, batch, count=len(batch))
            await self._wait_inflight()

    async def close(self, summary: Mapping[str, Any]) -> None:
        """Flush, write the end marker with `summary` and close the run log (no-op when none is open)."""
        await self.flush()
        async with self._lock:
            await self._wait_inflight()
            writer, self.writer = self.writer, None
            if writer is not None:
                batch = list(self._queue)  # appended while the last flush was being written
                self._queue.clear()
                self._submit(_write_batch, writer, batch, count=len(batch))
                self._submit(writer.close, summary, count=0)
                await self._wait_inflight()

    async def run(self, beat: Callable[[], None]) -> None:
        """The recorder task: flush every flush_s; while the disk is slow, keep beating and report it."""
        while True:
            beat()
            if self._inflight is not None and not self._inflight.done():
                began = time.monotonic()
                while not self._inflight.done():
                    await asyncio.wait({self._inflight}, timeout=min(self.stall_report_s, 1.0))
                    beat()
                    stalled = time.monotonic() - began
                    if stalled >= self.stall_report_s and not self._inflight.done():
                        self.last_error = f"run log write stalled for {stalled:.1f} s ({self.queued} queued)"
            elif self.writer is not None and self._queue and not self._lock.locked():
                batch = list(self._queue)
                self._queue.clear()
                self._submit(_write_batch, self.writer, batch, count=len(batch))
                continue
            await asyncio.sleep(self.flush_s)

    def _submit(self, work: Callable[..., None], *args: Any, count: int) -> None:
        """Queue work on the writer thread (FIFO, one thread: in order, never two at once)."""
        loop = asyncio.get_running_loop()
        future = loop.run_in_executor(self._thread, work, *args)
        future.add_done_callback(lambda done: self._written(done, count))
        self._inflight = future

    def _written(self, done: asyncio.Future[None], count: int) -> None:
        if done.cancelled():
            return
        exc = done.exception()
        if exc is None:
            self.records += count
            if self.last_error is not None and self.last_error.startswith("run log write stalled"):
                self.last_error = None
        elif isinstance(exc, GprbotError):  # disk full or gone: keep the robot running, report it
            self.last_error = str(exc)
            log.error("run log: %s", exc)
        else:
            self.last_error = f"{type(exc).__name__}: {exc}"
            log.error("run log write failed", exc_info=exc)

    async def _wait_inflight(self) -> None:
        """Wait for the write in flight; a cancelled waiter leaves it running, so it is never doubled."""
        inflight = self._inflight
        if inflight is not None and not inflight.done():
            await asyncio.wait({inflight})  # wait() never cancels what it waits for


def _write_batch(writer: RunLogWriter, batch: list[tuple[Any, float]]) -> None:
    for message, t in batch:
        writer.append(message, t)
