"""The inference worker: a separate process that does the heavy interpretation off the event loop.

Requests and replies are pickled dataclasses over a multiprocessing Pipe (spawn context). The event
loop hands each exchange to one dedicated thread (`run_in_executor`), which blocks in `poll`/`recv`
without the GIL, so the loop stays responsive. A worker that dies mid-job (segfault, OOM kill,
kill -9) shows up as EOF on the pipe: it is restarted and the job retried once; a second death is a
GprbotError and the next job gets a fresh worker. A job over its timeout kills the worker (a stuck
native call cannot be interrupted otherwise) and is not retried. This module imports no numpy at the
top, so that the child sets its thread counts before numpy/BLAS load.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import multiprocessing
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gprbot import errors
from gprbot.config import Config
from gprbot.errors import GprbotError
from gprbot.infer.worker_process import LineJobResult, serve

if TYPE_CHECKING:
    from multiprocessing.connection import Connection
    from multiprocessing.process import BaseProcess

    from gprbot.gpr.bscan import BScan
    from gprbot.reconstruct.survey_result import SurveyResult

_POLL_S = 0.05


@dataclass(frozen=True)
class WorkerHealth:
    """The worker's state for the daemon's status report."""

    alive: bool
    pid: int | None
    busy: bool
    jobs_done: int
    jobs_failed: int
    restarts: int
    last_error: str
    last_timings_s: dict[str, float]
    warmup_s: float


class _WorkerDiedError(Exception):
    """The worker process went away during an exchange (internal: turned into a retry or GprbotError)."""


class _WorkerTimeoutError(Exception):
    """A job ran past its timeout (internal)."""


@dataclass
class _Process:
    process: BaseProcess
    conn: Connection
    busy: bool = False


class InferenceWorker:
    """Owns the worker process: start it, send it jobs, restart it when it dies, report its health."""

    def __init__(self, cfg: Config, *, job_timeout_s: float = 300.0, start_timeout_s: float = 120.0,
                 threads: int = 2) -> None:
        self.cfg = cfg
        self.job_timeout_s = job_timeout_s
        self.start_timeout_s = start_timeout_s
        self.threads = threads
        self._context = multiprocessing.get_context("spawn")
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="inference-worker")
        self._lock = asyncio.Lock()
        self._worker: _Process | None = None
        self._jobs_done = self._jobs_failed = self._restarts = 0
        self._last_error = ""
        self._last_timings: dict[str, float] = {}
        self._warmup_s = 0.0
        self._closed = False

    async def start(self) -> None:
        """Start the worker process and wait until it has loaded and warmed up."""
        async with self._lock:
            if self._closed:
                raise GprbotError("the inference worker is closed; create a new InferenceWorker")
            if self._worker is None:
                await self._spawn()

    async def interpret_line(self, line: int, bscan: BScan, velocity_hint: float | None) -> LineJobResult:
        """Preprocess and interpret one line (velocity: the hint, the config's eps_r, or this line's fit)."""
        reply, timings = await self._job("interpret_line", (line, bscan, velocity_hint), f"line {line}")
        result: LineJobResult = reply
        self._last_timings = {**result.timings_s, **timings}
        return dataclasses.replace(result, timings_s=dict(self._last_timings))

    async def finish_survey(self, bscans: dict[int, BScan]) -> SurveyResult:
        """The whole survey through `reconstruct_survey` (one velocity from all lines), seeded by the config."""
        reply, timings = await self._job("finish_survey", (bscans,), f"the survey ({len(bscans)} lines)")
        result: SurveyResult = reply
        self._last_timings = {**result.timings_s, **timings}
        return dataclasses.replace(result, timings_s=dict(self._last_timings))

    async def write_outputs(self, out_dir: Path, result: SurveyResult, meta: dict[str, Any],
                            extent: tuple[float, float, float, float], truth_axes: list[Any],
                            raw_lines: dict[int, BScan]) -> list[Path]:
        """Write a survey's run directory (PLYs, exports, pictures) in the worker process; the paths written."""
        reply, _ = await self._job("write_outputs", (str(out_dir), result, meta, extent, truth_axes, raw_lines),
                                   f"the results of {out_dir.name}")
        return [Path(p) for p in reply]

    async def close(self) -> None:
        """Stop the worker process (a job in flight is killed and fails) and the exchange thread."""
        self._closed = True
        if self._lock.locked() and self._worker is not None:
            self._worker.process.kill()  # a job in flight ends now (shutdown must not wait for it)
        async with self._lock:
            if self._worker is not None:
                await asyncio.get_running_loop().run_in_executor(self._executor, _stop, self._worker)
                self._worker = None
        self._executor.shutdown(wait=False)

    def health(self) -> WorkerHealth:
        """A snapshot of the worker's state."""
        worker = self._worker
        alive = worker is not None and worker.process.is_alive()
        return WorkerHealth(alive, worker.process.pid if worker else None, bool(worker and worker.busy),
                            self._jobs_done, self._jobs_failed, self._restarts, self._last_error,
                            dict(self._last_timings), self._warmup_s)

    async def _job(self, kind: str, args: tuple[Any, ...], what: str) -> tuple[Any, dict[str, float]]:
        loop = asyncio.get_running_loop()
        async with self._lock:
            for attempt in (1, 2):
                if self._closed:
                    raise GprbotError("the inference worker is closed; create a new InferenceWorker")
                if self._worker is None:
                    await self._spawn()
                elif not self._worker.process.is_alive():  # died between jobs
                    self._restarts += 1
                    await self._replace(self._worker)
                worker = self._worker
                assert worker is not None
                began = time.perf_counter()
                try:
                    reply = await loop.run_in_executor(self._executor, _exchange, worker, (kind, args),
                                                       self.job_timeout_s)
                except _WorkerDiedError as exc:
                    if self._closed:
                        self._jobs_failed += 1
                        raise GprbotError(f"the inference worker was closed during {what}") from None
                    self._restarts += 1
                    self._last_error = f"worker died during {what}: {exc}"
                    await self._replace(worker)
                    if attempt == 2:
                        self._jobs_failed += 1
                        raise GprbotError(f"the inference worker died twice on {what} ({exc}); the job is dropped "
                                          "and the worker restarted — check memory (dmesg) and the input") from None
                    continue
                except _WorkerTimeoutError:
                    self._restarts += 1
                    self._jobs_failed += 1
                    self._last_error = f"{what} ran past the {self.job_timeout_s:.3g} s job timeout"
                    await self._replace(worker, force=True)
                    raise GprbotError(f"inference of {what} ran past {self.job_timeout_s:.3g} s; the worker "
                                      "was restarted — raise the job timeout or check the input size") from None
                except asyncio.CancelledError:
                    worker.process.kill()  # the exchange thread then sees EOF and returns
                    self._worker = None
                    raise
                return self._reply(reply, what, time.perf_counter() - began)
        raise AssertionError("unreachable")

    def _reply(self, reply: tuple[Any, ...], what: str, round_trip_s: float) -> tuple[Any, dict[str, float]]:
        if reply[0] == "done":
            _, result, compute_s = reply
            self._jobs_done += 1
            timings = {"worker_compute": compute_s, "round_trip": round_trip_s,
                       "transfer": max(round_trip_s - compute_s, 0.0)}
            return result, timings
        _, name, message, trace = reply
        self._jobs_failed += 1
        self._last_error = f"{what}: {name}: {message}"
        error = getattr(errors, name, None)
        if isinstance(error, type) and issubclass(error, GprbotError):
            raise error(message)
        raise GprbotError(f"the inference worker failed on {what}: {name}: {message}\n{trace}")

    async def _spawn(self) -> None:
        loop = asyncio.get_running_loop()
        parent, child = self._context.Pipe()
        process = self._context.Process(target=serve, args=(child, self.cfg, self.threads),
                                        name="gprbot-inference", daemon=True)
        await loop.run_in_executor(self._executor, process.start)
        child.close()  # the child's death must read as EOF here
        worker = _Process(process, parent)
        try:
            ready = await loop.run_in_executor(self._executor, _await_ready, worker, self.start_timeout_s)
        except (_WorkerDiedError, _WorkerTimeoutError) as exc:
            await loop.run_in_executor(self._executor, _stop, worker)
            raise GprbotError(f"the inference worker did not start ({exc}); its traceback is on stderr (the "
                              "journal); a script that starts it needs an `if __name__ == '__main__':` guard") from None
        self._warmup_s = float(ready["warmup_s"])
        self._worker = worker

    async def _replace(self, worker: _Process, force: bool = False) -> None:
        await asyncio.get_running_loop().run_in_executor(self._executor, _stop, worker, force)
        self._worker = None
        await self._spawn()


def _exchange(worker: _Process, request: tuple[str, tuple[Any, ...]], timeout_s: float) -> tuple[Any, ...]:
    """Send a job and wait for its reply (runs in the exchange thread)."""
    deadline = time.monotonic() + timeout_s
    try:
        try:
            worker.conn.send(request)
        except OSError as exc:
            raise _WorkerDiedError(f"the pipe is broken ({exc})") from exc
        while True:
            reply = _receive(worker, deadline)
            if reply[0] != "started":
                return reply
            worker.busy = True
    finally:
        worker.busy = False


def _await_ready(worker: _Process, timeout_s: float) -> dict[str, Any]:
    reply = _receive(worker, time.monotonic() + timeout_s)
    if reply[0] != "ready":
        raise _WorkerDiedError(f"unexpected first message {reply[0]!r}")
    info: dict[str, Any] = reply[1]
    return info


def _receive(worker: _Process, deadline: float) -> tuple[Any, ...]:
    try:
        while not worker.conn.poll(min(max(deadline - time.monotonic(), 0.0), _POLL_S)):
            if not worker.process.is_alive():
                raise _WorkerDiedError(f"exit code {worker.process.exitcode}")
            if time.monotonic() >= deadline:
                raise _WorkerTimeoutError()
        reply: tuple[Any, ...] = worker.conn.recv()
    except (EOFError, OSError) as exc:
        worker.process.join(1.0)
        raise _WorkerDiedError(f"exit code {worker.process.exitcode}") from exc
    return reply


def _stop(worker: _Process, force: bool = False) -> None:
    """Ask the worker to stop (force: a busy one is killed at once), then kill it if it does not."""
    if force:
        worker.process.kill()
    with contextlib.suppress(OSError):
        worker.conn.send(("stop", ()))
    worker.process.join(2.0)
    if worker.process.is_alive():
        worker.process.kill()
        worker.process.join(2.0)
    worker.conn.close()
