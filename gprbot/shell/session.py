"""One shell session over any byte stream (TCP or serial): parse lines, enforce the rules, reply in order.

A reader task turns bytes into lines. `estop` is executed the moment its line is read — ahead of
anything queued, without auth or rate limit — and its reply is written at once. Every other line
becomes a job on a bounded FIFO; one worker runs the jobs in order and writes their replies, so each
line gets exactly one reply, in order (the e-stop's may overtake). A full queue stops reading
(backpressure), so `handle()` must return promptly. Commands received before the client's end of
input still run (`printf 'survey start\n' | nc robot 7878` works); after a connection reset they don't.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path

from gprbot.errors import GprbotError
from gprbot.shell import runfiles
from gprbot.shell.auth import token_matches
from gprbot.shell.commands import (
    Auth,
    CommandError,
    Empty,
    ErrorCode,
    Estop,
    Files,
    Help,
    Pull,
    Runs,
    help_lines,
    parse_command,
)
from gprbot.shell.handler import CommandHandler, EventBus, RobotCommand, SessionInfo
from gprbot.shell.protocol import LineReceived, LineRejected, LineSplitter, Reply, encode_event, encode_reply

log = logging.getLogger(__name__)
_STREAM_CHUNK = 1 << 16


@dataclass(frozen=True)
class SessionLimits:
    """Per-session limits (shared by TCP and serial)."""

    max_line: int = 256
    rate_per_s: float = 20.0
    max_pending: int = 32
    handler_timeout_s: float = 10.0
    max_output_buffer: int = 1 << 20
    max_auth_failures: int = 5


class RateLimiter:
    """A token bucket: `rate_per_s` commands a second on average, bursts up to `rate_per_s`."""

    def __init__(self, rate_per_s: float, now: float) -> None:
        self.rate_per_s = rate_per_s
        self._tokens = max(rate_per_s, 1.0)
        self._last = now

    def allow(self, now: float) -> bool:
        """Take one token if there is one at time `now` (seconds, monotonic)."""
        capacity = max(self.rate_per_s, 1.0)
        self._tokens = min(capacity, self._tokens + (now - self._last) * self.rate_per_s)
        self._last = now
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False


Job = Callable[[], Awaitable["Reply | runfiles.OpenedFile"]]


class Session:
    """Serve one client until it disconnects or `close()` is called."""

    def __init__(
        self,
        handler: CommandHandler,
        info: SessionInfo,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        events: EventBus,
        *,
        token: str | None = None,
        limits: SessionLimits = SessionLimits(),
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.info = info
        self._handler, self._reader, self._writer, self._events = handler, reader, writer, events
        self._token, self._limits, self._clock = token, limits, clock
        self._splitter = LineSplitter(limits.max_line)
        self._rate = RateLimiter(limits.rate_per_s, clock())
        self._jobs: asyncio.Queue[Job | None] = asyncio.Queue(maxsize=limits.max_pending)
        self._in_payload = False
        self._deferred: list[bytes] = []
        self._auth_failures = 0
        self._closed = False
        self.lines_seen = 0

    async def run(self) -> None:
        """Read and answer lines until end of input; then finish the queued replies and close."""
        unsubscribe = self._events.subscribe(self._send_event)
        worker = asyncio.create_task(self._work(), name=f"shell-session-{self.info.id}-worker")
        try:
            while not self._closed:
                try:
                    data = await self._reader.read(4096)
                except (ConnectionError, OSError):
                    break
                if not data:
                    break
                for item in self._splitter.feed(data):
                    if self._closed:
                        break
                    self.lines_seen += 1
                    await self._dispatch(item)
            await self._jobs.put(None)
            await worker
        finally:
            unsubscribe()
            worker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await worker
            self.close()

    def close(self) -> None:
        """Drop the connection now (idempotent)."""
        self._closed = True
        if not self._writer.is_closing():
            self._writer.close()
        self._reader.feed_eof()

    async def _dispatch(self, item: LineReceived | LineRejected) -> None:
        if isinstance(item, LineRejected):
            await self._queue_reply(Reply.failure(item.code, item.text))
            return
        try:
            command = parse_command(item.text)
        except CommandError as exc:
            await self._queue_reply(Reply.failure(exc.code, exc.text))
            return
        if isinstance(command, Estop):
            self._send_line(encode_reply(await self._estop()))
            return
        if not self._rate.allow(self._clock()):
            limit = self._limits.rate_per_s
            await self._queue_reply(Reply.failure(ErrorCode.RATE_LIMITED, f"more than {limit:g} commands/s; slow down"))
        elif isinstance(command, Empty):
            await self._queue_reply(Reply.success())
        elif isinstance(command, Help):
            topic = command.topic
            await self._queue(lambda: self._help(topic))
        elif isinstance(command, Auth):
            await self._queue_reply(self._authenticate(command.token))
        elif self._token is not None and not self.info.authenticated:
            text = "send `auth TOKEN` first (estop and help work without)"
            await self._queue_reply(Reply.failure(ErrorCode.UNAUTHORIZED, text))
        elif isinstance(command, Runs | Files | Pull):
            files_command = command
            await self._queue(lambda: self._guarded(asyncio.to_thread(self._run_files, files_command)))
        else:
            robot_command: RobotCommand = command
            await self._queue(lambda: self._guarded(self._ask_robot(robot_command)))

    async def _queue_reply(self, reply: Reply) -> None:
        async def job() -> Reply:
            return reply

        await self._queue(job)

    async def _queue(self, job: Job) -> None:
        await self._jobs.put(job)

    async def _help(self, topic: str | None) -> Reply:
        try:
            return Reply.success("help", help_lines(topic))
        except CommandError as exc:
            return Reply.failure(exc.code, exc.text)

    def _authenticate(self, given: str) -> Reply:
        if self._token is None:
            return Reply.success("auth not required on this server")
        if token_matches(self._token, given):
            self.info.authenticated = True
            self._auth_failures = 0
            return Reply.success("auth")
        self._auth_failures += 1
        log.warning("shell: bad token from %s (%d)", self.info.peer, self._auth_failures)
        if self._auth_failures >= self._limits.max_auth_failures:
            self._closed = True  # the reply below is still written, then the session ends
        return Reply.failure(ErrorCode.UNAUTHORIZED, "wrong token")

    async def _estop(self) -> Reply:
        log.warning("shell: estop from %s", self.info.peer)
        try:
            return await asyncio.wait_for(self._handler.estop(self.info), self._limits.handler_timeout_s)
        except Exception as exc:
            log.critical("shell: estop handler failed", exc_info=True)
            return Reply.failure(ErrorCode.INTERNAL, f"estop failed: {exc!r}; use the hardware e-stop")

    async def _ask_robot(self, command: RobotCommand) -> Reply:
        return await asyncio.wait_for(self._handler.handle(command, self.info), self._limits.handler_timeout_s)

    async def _guarded(self, work: Awaitable[Reply | runfiles.OpenedFile]) -> Reply | runfiles.OpenedFile:
        """Await a command's work; every failure becomes an error reply (the session goes on)."""
        try:
            return await work
        except CommandError as exc:
            return Reply.failure(exc.code, exc.text)
        except TimeoutError:
            text = f"the robot did not answer within {self._limits.handler_timeout_s:g} s"
            return Reply.failure(ErrorCode.INTERNAL, text)
        except GprbotError as exc:
            return Reply.failure(ErrorCode.INTERNAL, str(exc))
        except Exception as exc:
            log.exception("shell: command failed")
            return Reply.failure(ErrorCode.INTERNAL, f"{type(exc).__name__}: {exc}")

    def _run_files(self, command: Runs | Files | Pull) -> Reply | runfiles.OpenedFile:
        runs_dir = Path(self._handler.runs_dir())
        if isinstance(command, Runs):
            names = runfiles.list_runs(runs_dir)
            return Reply.success(f"runs {len(names)}", names)
        if isinstance(command, Files):
            files = runfiles.list_files(runs_dir, command.run)
            return Reply.success(f"files {len(files)}", [f"{size} {name}" for name, size in files])
        return runfiles.open_run_file(runs_dir, command.run, command.file)

    async def _work(self) -> None:
        while (job := await self._jobs.get()) is not None:
            if self._writer.is_closing():
                continue  # the client is gone: its queued jogs must not move the robot
            try:
                outcome = await job()
            except Exception as exc:  # a bug must cost one reply, never the session
                log.exception("shell: job failed")
                outcome = Reply.failure(ErrorCode.INTERNAL, f"{type(exc).__name__}: {exc}")
            try:
                if isinstance(outcome, runfiles.OpenedFile):
                    await self._stream(outcome)
                else:
                    self._send_line(encode_reply(outcome))
                    await self._writer.drain()
            except (ConnectionError, OSError):
                self.close()

    async def _stream(self, opened: runfiles.OpenedFile) -> None:
        with opened.handle:
            self._send_line(encode_reply(Reply.success(f"pull {opened.size} {opened.sha256}")))
            self._in_payload = True
            try:
                left = opened.size
                while left:
                    chunk = await asyncio.to_thread(opened.handle.read, min(_STREAM_CHUNK, left))
                    if not chunk:  # the file shrank: the byte count is promised, so the stream is broken
                        log.error("shell: %s shrank during pull; dropping %s", opened.path, self.info.peer)
                        self.close()
                        return
                    self._writer.write(chunk)
                    left -= len(chunk)
                    await self._writer.drain()
            finally:
                self._in_payload = False
                deferred, self._deferred = self._deferred, []
                for data in deferred:
                    self._send_line(data)

    def _send_line(self, data: bytes) -> None:
        if self._writer.is_closing():
            return
        if self._in_payload:
            self._deferred.append(data)
        else:
            self._writer.write(data)

    def _send_event(self, text: str) -> None:
        if self._writer.is_closing():
            return
        if self._writer.transport.get_write_buffer_size() > self._limits.max_output_buffer:
            log.warning("shell: %s is not reading its events; dropping it", self.info.peer)
            self.close()
            return
        self._send_line(encode_event(text))
