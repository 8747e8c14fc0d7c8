"""`gprbot demo` through the daemon: start it in-process on the simulated robot, drive it over its TCP
shell like an operator (`survey start`, events, `files`, `pull`), stop it as systemd would."""

from __future__ import annotations

import asyncio
import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from gprbot.config import Config
from gprbot.daemon import serve
from gprbot.errors import GprbotError
from gprbot.robot.runtime import RobotRuntime
from gprbot.shell.protocol import PayloadChunk, ReplyReader, ServerEvent, ServerReply


@dataclass(frozen=True)
class ShellDemoResult:
    """What the online demo produced: the run directory, its files and the pulled pipes.json."""

    run_dir: Path
    files: tuple[str, ...]
    pipes_json: bytes
    exit_status: int


class ShellConnection:
    """A small client of the line protocol: commands, replies, events and pulled payloads."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                 on_event: Callable[[str], None]) -> None:
        self.reader, self.writer, self.on_event = reader, writer, on_event
        self._parser = ReplyReader()
        self._items: list[ServerReply | PayloadChunk] = []
        self.events: list[str] = []

    async def command(self, line: str) -> ServerReply:
        """Send one command; its reply (GprbotError if it is an error reply)."""
        self.writer.write(line.encode() + b"\n")
        await self.writer.drain()
        reply = await self._next()
        if not isinstance(reply, ServerReply):
            raise GprbotError(f"unexpected payload before the reply to {line!r}")
        if not reply.ok:
            raise GprbotError(f"`{line}` failed: {reply.code} {reply.text}")
        return reply

    async def pull(self, run: str, name: str) -> bytes:
        """`pull RUN FILE`: the file's bytes, checked against the announced sha256."""
        reply = await self.command(f"pull {run} {name}")
        data = bytearray()
        while len(data) < (reply.payload_size or 0):
            chunk = await self._next()
            assert isinstance(chunk, PayloadChunk)
            data += chunk.data
        if hashlib.sha256(data).hexdigest() != reply.payload_sha256:
            raise GprbotError(f"pulled {name} does not match its sha256; pull it again")
        return bytes(data)

    async def wait_event(self, prefix: str | tuple[str, ...]) -> str:
        """Wait for an event line starting with `prefix` (or one of several)."""
        while True:
            for event in self.events:
                if event.startswith(prefix):
                    return event
            await self._read()

    async def _next(self) -> ServerReply | PayloadChunk:
        while not self._items:
            await self._read()
        return self._items.pop(0)

    async def _read(self) -> None:
        data = await self.reader.read(1 << 16)
        if not data:
            raise GprbotError("the daemon closed the shell connection")
        for item in self._parser.feed(data):
            if isinstance(item, ServerEvent):
                self.events.append(item.text)
                self.on_event(item.text)
            else:
                self._items.append(item)


async def survey_via_shell(cfg: Config, *, timeout_s: float = 900.0,
                           on_event: Callable[[str], None] = lambda _: None) -> ShellDemoResult:
    """Run the daemon on `cfg` (simulated), survey through its TCP shell, pull pipes.json, shut it down."""
    stop = asyncio.Event()
    started: list[RobotRuntime] = []
    daemon = asyncio.create_task(serve(cfg, shell_port=0, stop=stop, on_ready=started.append))  # type: ignore[arg-type]
    try:
        async with asyncio.timeout(timeout_s):
            while not started or started[0].shell is None:
                if daemon.done():
                    raise GprbotError(f"the daemon did not start (exit status {daemon.result()}); see the log")
                await asyncio.sleep(0.05)
            runtime = started[0]
            shell = ShellConnection(*await asyncio.open_connection("127.0.0.1", runtime.shell_port), on_event)
            await shell.command("status")
            run = (await shell.command("survey start")).text.split()[1]
            outcome = await shell.wait_event((f"survey done {run}", f"survey failed {run}"))
            if outcome.startswith("survey failed"):
                raise GprbotError(outcome)
            files = (await shell.command(f"files {run}")).body
            pipes = await shell.pull(run, "pipes.json")
            shell.writer.close()
    finally:
        stop.set()
        status = await daemon
    return ShellDemoResult(Path(cfg.runs_dir) / run, tuple(line.split(" ", 1)[1] for line in files), pipes, status)
