"""One shell session over any byte stream (TCP or serial): parse lines, enforce the rules, reply in order.

A reader task turns bytes into lines. `estop` is executed the moment its line is read — ahead of
anything queued, without auth or rate limit — and its reply is written at once. Every other line
becomes a job on a bounded FIFO; one worker runs the jobs in order and writes their replies, so each
line gets exactly one reply, in order (the e-stop's may overtake). A full queue stops reading
(backpressure), so `handle()` must return promptly. Commands received before the client's end of
input still run (`printf 'survey start\n' | nc robot 7878` works); after a connection reset they don't.

A session starts *pending*: it must authenticate (or, on a server without a token, send a line) before
its deadline, or it is closed; the server's `admit` then decides whether there is room for it. An
admitted session is closed after `idle_timeout_s` without input. Unauthenticated sessions get no
events. Everything a client can make the session hold is bounded: the job queue, the replies held back
while a file streams, the transport's output buffer (a client that stops reading is dropped).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path

from gprbot.errors import GprbotError
from gprbot.shell import runfiles
from gprbot.shell.auth import AuthGuard, token_matches
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
from gprbot.shell.ratelog import RateLimitedLog

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
    auth_timeout_s: float = 10.0  # a pending session must authenticate (or send a line) within this
    idle_timeout_s: float | None = 1800.0  # an admitted session without input this long is closed
    max_deferred_bytes: int = 64 * 1024  # replies and events held back while a file streams


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
Admit = Callable[["Session"], "str | None"]  # None: admitted; else why not (the session is then closed)
_quiet_log = RateLimitedLog(log)  # shared by every session: a flood of clients is one flood of lines


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
        admit: Admit | None = None,
        pending_deadline_s: float | None = None,
        guard: AuthGuard | None = None,
        quiet_log: RateLimitedLog = _quiet_log,
    ) -> None:
        self.info = info
        self.admitted = admit is None  # the serial console (and tests' bare sessions) start admitted
        self._admit = admit
        self._pending_deadline_s = limits.auth_timeout_s if pending_deadline_s is None else pending_deadline_s
        self._guard = guard
        self._quiet = quiet_log
        self._deferred_bytes = 0
        self.events_dropped = 0
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
        loop = asyncio.get_running_loop()
        pending_until = loop.time() + self._pending_deadline_s  # fixed: trickling bytes do not extend it
        try:
            while not self._closed:
                if self.admitted:
                    limit, why = self._limits.idle_timeout_s, f"idle for {self._limits.idle_timeout_s:g} s"
                else:
                    limit = max(0.0, pending_until - loop.time())
                    why = ("not authenticated" if self._token is not None else "no command") + \
                        f" within {self._pending_deadline_s:g} s"
                try:
                    async with asyncio.timeout(limit):
                        data = await self._reader.read(4096)
                except TimeoutError:
                    self._quiet.log(logging.INFO, "timeout", "shell: closing %s: %s", self.info.peer, why)
                    self._send_line(encode_event(f"closing: {why}"))
                    break
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
            await asyncio.wait({worker})  # not `await worker`: that would swallow a cancel of this task
            self.close()

    def close(self) -> None:
        """Drop the connection now (idempotent); output already written is still sent."""
        self._closed = True
        if not self._writer.is_closing():
            self._writer.close()
        self._reader.feed_eof()

    def abort(self) -> None:
        """Drop the connection and whatever output it has not sent (shutdown, a client not reading)."""
        self.close()
        self._writer.transport.abort()

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
        if not self.admitted and self._token is None and not self._admitted_now():
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
            await self._queue_reply(self._authenticate(command))
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

    def _admitted_now(self) -> bool:
        """Ask the server for a slot; without one, reply busy and end the session."""
        refusal = self._admit(self) if self._admit is not None else None
        if refusal is None:
            self.admitted = True
            return True
        self._send_line(encode_reply(Reply.failure(ErrorCode.BUSY, refusal)))
        self._closed = True
        return False

    def _authenticate(self, command: Auth) -> Reply:
        if self._token is None:
            return Reply.success("auth not required on this server")
        host = self.info.peer.rpartition(":")[0] or self.info.peer
        now = self._clock()
        refusal = self._guard.refusal(host, now) if self._guard is not None else None
        if refusal is not None:
            self._closed = True
            self._quiet.log(logging.WARNING, f"auth:{host}", "shell: %s: %s", self.info.peer, refusal)
            return Reply.failure(ErrorCode.UNAUTHORIZED, refusal)
        # the quoted word (what our client sends) or the raw rest of the line (typed into nc)
        good = token_matches(self._token, command.token) | token_matches(self._token, command.raw or command.token)
        if good:
            if self._guard is not None:
                self._guard.succeeded(host)
            if not self.admitted:
                refusal = self._admit(self) if self._admit is not None else None
                if refusal is not None:
                    self._closed = True
                    return Reply.failure(ErrorCode.BUSY, refusal)
                self.admitted = True
            self.info.authenticated = True
            self._auth_failures = 0
            return Reply.success("auth")
        self._auth_failures += 1
        locked = self._guard.failed(host, now) if self._guard is not None else False
        self._quiet.log(logging.WARNING, f"auth:{host}", "shell: bad token from %s (%d)",
                        self.info.peer, self._auth_failures)
        if locked or self._auth_failures >= self._limits.max_auth_failures:
            self._closed = True  # the reply below is still written, then the session ends
        return Reply.failure(ErrorCode.UNAUTHORIZED, "wrong token")

    async def _estop(self) -> Reply:
        self._quiet.log(logging.WARNING, f"estop:{self.info.peer}", "shell: estop from %s", self.info.peer)
        try:  # not wait_for: on 3.11 it can swallow a cancel, and this is the e-stop
            async with asyncio.timeout(self._limits.handler_timeout_s):
                return await self._handler.estop(self.info)
        except Exception as exc:
            log.critical("shell: estop handler failed", exc_info=True)
            return Reply.failure(ErrorCode.INTERNAL, f"estop failed: {exc!r}; use the hardware e-stop")

    async def _ask_robot(self, command: RobotCommand) -> Reply:
        async with asyncio.timeout(self._limits.handler_timeout_s):
            return await self._handler.handle(command, self.info)

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
                deferred, self._deferred, self._deferred_bytes = self._deferred, [], 0
                for data in deferred:
                    self._send_line(data)

    def _send_line(self, data: bytes, droppable: bool = False) -> None:
        """Write a reply or event line now, or hold it back while a file streams (bounded either way)."""
        if self._writer.is_closing():
            return
        if self._in_payload:
            if self._deferred_bytes + len(data) > self._limits.max_deferred_bytes:
                if droppable:
                    self.events_dropped += 1
                    return
                self._drop(f"{self._deferred_bytes} bytes of replies held back during a pull")
                return
            self._deferred.append(data)
            self._deferred_bytes += len(data)
            return
        if self._writer.transport.get_write_buffer_size() > self._limits.max_output_buffer:
            self._drop("it is not reading what it is sent")
            return
        self._writer.write(data)

    def _drop(self, why: str) -> None:
        self._quiet.log(logging.WARNING, "drop", "shell: dropping %s: %s", self.info.peer, why)
        self.close()

    def _send_event(self, text: str) -> None:
        if self.info.authenticated:  # an unauthenticated client learns nothing about the robot
            self._send_line(encode_event(text), droppable=True)
