"""The recorder: queues every raw message while a run log is open and writes it off the event loop.

Producers call `append` (cheap: a deque append). The recorder task drains the queue every
`flush_s` and writes the batch in a thread, so the run log's writes and periodic fsync never stall
the control loop. `open`/`close` bracket one run (a survey).
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from gprbot.errors import GprbotError
from gprbot.runlog import RunLogWriter


class Recorder:
    """Owns the open RunLogWriter (if any) and the queue of messages waiting to be written."""

    def __init__(self, flush_s: float = 0.05) -> None:
        self.flush_s = flush_s
        self.writer: RunLogWriter | None = None
        self.run_dir: Path | None = None
        self.records = 0
        self.last_error: str | None = None
        self._queue: deque[tuple[Any, float]] = deque()
        self._lock = asyncio.Lock()

    @property
    def recording(self) -> bool:
        """Whether a run log is open."""
        return self.writer is not None

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
        """Write everything queued so far (in a thread)."""
        async with self._lock:
            writer = self.writer
            if writer is None or not self._queue:
                return
            batch = list(self._queue)
            self._queue.clear()
            await asyncio.to_thread(_write_batch, writer, batch)
            self.records += len(batch)

    async def close(self, summary: Mapping[str, Any]) -> None:
        """Flush, write the end marker with `summary` and close the run log (no-op when none is open)."""
        await self.flush()
        async with self._lock:
            writer, self.writer = self.writer, None
            self._queue.clear()
            if writer is not None:
                await asyncio.to_thread(writer.close, summary)

    async def run(self, beat: Callable[[], None]) -> None:
        """The recorder task: flush every flush_s."""
        while True:
            beat()
            try:
                await self.flush()
            except GprbotError as exc:  # disk full or gone: keep the robot running, report it
                self.last_error = str(exc)
            await asyncio.sleep(self.flush_s)


def _write_batch(writer: RunLogWriter, batch: list[tuple[Any, float]]) -> None:
    for message, t in batch:
        writer.append(message, t)
