"""The shell's client side: a connection that pairs requests with replies, and `pull_run`.

The interactive `gprbot shell` lives in gprbot/shell/interactive.py; both share ShellConnection.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import math
import os
import shlex
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path, PurePosixPath
from types import TracebackType
from typing import TypeVar

from gprbot.config import DEFAULT_SHELL_PORT
from gprbot.errors import GprbotError, ProtocolError
from gprbot.shell.protocol import PayloadChunk, ReplyReader, ServerEvent, ServerReply

DEFAULT_PORT = DEFAULT_SHELL_PORT
_Item = TypeVar("_Item", ServerReply, PayloadChunk)
REPLY_TIMEOUT_S = 30.0
MAX_PULL_BYTES = 64 << 30  # 64 GiB: far above any run file (log segments are 64 MiB), far below 15 digits

PULL_RATE_PER_S = 10.0  # the shell allows 20 commands/s a session (shell.rate_per_s); pull at half that


class ShellCommandError(GprbotError):
    """The server answered `error <code> <text>`."""

    def __init__(self, reply: ServerReply) -> None:
        super().__init__(f"server said: error {reply.code} {reply.text}")
        self.reply = reply


def parse_address(text: str, default_port: int = DEFAULT_PORT) -> tuple[str, int]:
    """'host', 'host:port', '[v6]:port' → (host, port)."""
    if text.startswith("["):
        host, _, rest = text[1:].partition("]")
        port_text = rest[1:] if rest.startswith(":") else ""
    elif text.count(":") == 1:
        host, _, port_text = text.partition(":")
    else:
        host, port_text = text, ""
    if not host:
        raise GprbotError(f"no host in {text!r}; expected HOST[:PORT]")
    if not port_text:
        return host, default_port
    if not port_text.isdigit() or not 0 < int(port_text) < 65536:
        raise GprbotError(f"bad port in {text!r}; expected HOST[:PORT] with PORT in 1..65535")
    return host, int(port_text)


class ShellConnection:
    """One connection to a gprbot shell; `request()` one command at a time, events go to `on_event`."""

    def __init__(self, host: str, port: int, on_event: Callable[[str], None] | None = None) -> None:
        self.host, self.port = host, port
        self.on_event = on_event
        self._writer: asyncio.StreamWriter | None = None
        self._task: asyncio.Task[None] | None = None
        self._replies: asyncio.Queue[ServerReply | BaseException] = asyncio.Queue()
        self._payload: asyncio.Queue[PayloadChunk | BaseException] = asyncio.Queue()

    async def __aenter__(self) -> ShellConnection:
        await self.open()
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()

    async def open(self, timeout_s: float = 10.0) -> None:
        """Connect (GprbotError if the robot cannot be reached)."""
        try:
            async with asyncio.timeout(timeout_s):
                stream, self._writer = await asyncio.open_connection(self.host, self.port)
        except (OSError, TimeoutError) as exc:
            raise GprbotError(f"cannot connect to {self.host}:{self.port}: {exc}; is gprbot running there?") from exc
        self._task = asyncio.create_task(self._read_loop(stream))

    async def close(self) -> None:
        """Disconnect."""
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        if self._writer is not None:
            self._writer.close()
            with contextlib.suppress(ConnectionError, OSError):
                await self._writer.wait_closed()

    async def request(self, line: str, timeout_s: float = REPLY_TIMEOUT_S) -> ServerReply:
        """Send one command line and return its reply (error replies are returned, not raised)."""
        if self._writer is None:
            raise GprbotError("not connected; call open() first")
        self._writer.write(line.encode("utf-8") + b"\n")
        await self._writer.drain()
        return await self._next(self._replies, timeout_s)

    async def check(self, line: str) -> ServerReply:
        """Like request(), but an `error` reply raises ShellCommandError."""
        reply = await self.request(line)
        if not reply.ok:
            raise ShellCommandError(reply)
        return reply

    async def authenticate(self, token: str) -> None:
        """Send `auth TOKEN` (ShellCommandError if refused)."""
        await self.check(f"auth {_quote(token)}")  # the server splits lines like a shell

    async def pull_file(self, run: str, name: str, target: Path, expected_size: int | None = None,
                        max_size: int = MAX_PULL_BYTES) -> Path:
        """Fetch one file, verify its sha256 and move it into place atomically; returns `target`.

        The size the server announces is checked before a byte is stored: against the size `files`
        listed (when given), the cap, and the free space where it goes."""
        header = await self.check(f"pull {_quote(run)} {_quote(name)}")
        size = header.payload_size
        if size is None:
            raise ProtocolError(f"server answered pull without a size: {header.text!r}")
        target.parent.mkdir(parents=True, exist_ok=True)
        problem = None
        if expected_size is not None and size != expected_size:
            problem = f"the server announced {size} bytes for {run}/{name}, but listed {expected_size}"
        elif size > max_size:
            problem = f"the server announced {size} bytes for {run}/{name}, over the {max_size}-byte cap"
        elif size > shutil.disk_usage(target.parent).free:
            problem = f"{run}/{name} is {size} bytes, more than the free space in {target.parent}"
        if problem is not None:
            await self.close()  # the payload follows the header: this connection cannot be used again
            raise ProtocolError(f"{problem}; refusing it")
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
        digest = hashlib.sha256()
        try:
            with os.fdopen(fd, "wb") as out:
                while True:  # a 0-byte file still gets one (empty) last chunk
                    chunk = await self._next(self._payload, REPLY_TIMEOUT_S)
                    out.write(chunk.data)
                    digest.update(chunk.data)
                    if chunk.last:
                        break
                out.flush()
                os.fsync(out.fileno())
            if digest.hexdigest() != header.payload_sha256:
                raise ProtocolError(f"{run}/{name}: sha256 mismatch ({digest.hexdigest()} != {header.payload_sha256})")
            os.replace(tmp_name, target)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp_name)
            raise
        return target

    async def _next(self, queue: asyncio.Queue[_Item | BaseException], timeout_s: float) -> _Item:
        try:
            async with asyncio.timeout(timeout_s):
                item = await queue.get()
        except TimeoutError:
            raise GprbotError(f"no answer from {self.host}:{self.port} within {timeout_s:g} s") from None
        if isinstance(item, BaseException):
            raise item
        return item

    async def _read_loop(self, stream: asyncio.StreamReader) -> None:
        parser = ReplyReader()
        failure: BaseException = GprbotError(f"{self.host}:{self.port} closed the connection")
        try:
            while data := await stream.read(65536):
                for item in parser.feed(data):
                    if isinstance(item, ServerEvent):
                        if self.on_event is not None:
                            self.on_event(item.text)
                    elif isinstance(item, PayloadChunk):
                        self._payload.put_nowait(item)
                    else:
                        self._replies.put_nowait(item)
        except (ProtocolError, ConnectionError, OSError) as exc:
            failure = exc if isinstance(exc, ProtocolError) else GprbotError(f"connection lost: {exc}")
        self._replies.put_nowait(failure)
        self._payload.put_nowait(failure)


def _quote(text: str) -> str:
    return shlex.quote(text)


def safe_relative(name: str) -> PurePosixPath:
    """A server-supplied file name as a relative path that cannot leave the destination directory."""
    path = PurePosixPath(name)
    if path.is_absolute() or not path.parts or any(p in ("..", ".", "") for p in path.parts) or "\\" in name:
        raise ProtocolError(f"server listed an unsafe file name {name!r}; refusing it")
    return path


async def pull_run(host: str, port: int, run: str, dest: Path, token: str | None = None) -> list[Path]:
    """Download every file of `run` into `dest` (sha256-checked, atomic per file); returns the paths written."""
    written: list[Path] = []
    async with ShellConnection(host, port) as conn:
        if token is not None:
            await conn.authenticate(token)
        listing = await conn.check(f"files {_quote(run)}")
        last = -math.inf
        for line in listing.body:
            size_text, _, name = line.partition(" ")
            if not size_text.isdigit():
                raise ProtocolError(f"bad `files` line from the server: {line!r}")
            relative = safe_relative(name)
            # Stay under the shell's per-session command rate: a run has dozens of small files
            # (the exported survey lines), which would otherwise be asked for faster than it allows.
            wait = last + 1.0 / PULL_RATE_PER_S - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)
            last = time.monotonic()
            written.append(await conn.pull_file(run, name, dest.joinpath(*relative.parts), int(size_text)))
    return written
