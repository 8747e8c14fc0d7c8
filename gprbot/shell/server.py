"""The shell's transports: a TCP server and a serial console, both running the same Session logic."""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import serial

from gprbot.config import DEFAULT_SHELL_PORT
from gprbot.errors import ConfigError, DriverError
from gprbot.shell.auth import AuthGuard, load_token
from gprbot.shell.commands import ErrorCode
from gprbot.shell.handler import CommandHandler, EventBus, SessionInfo
from gprbot.shell.protocol import Reply, encode_reply
from gprbot.shell.ratelog import RateLimitedLog
from gprbot.shell.session import Session, SessionLimits

log = logging.getLogger(__name__)


def is_loopback(host: str) -> bool:
    """True for addresses only this machine can reach (127.0.0.0/8, ::1, 'localhost')."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name or '' (all interfaces): assume reachable from outside


class ShellServer:
    """The TCP shell. A token file is required unless it listens on loopback only.

    Slots: at most `max_clients` admitted sessions, `max_unauthenticated` pending ones (each closed if it
    does not authenticate within `auth_timeout_s`) and `max_overflow` more that arrive when those are
    full, kept only `overflow_window_s` — long enough for an `estop`, which every session accepts, or an
    `auth` that finds a free slot. Beyond that a connection gets `error busy` at once. Wrong tokens are
    counted per host across connections (`AuthGuard`).
    """

    def __init__(
        self,
        handler: CommandHandler,
        *,
        host: str = "127.0.0.1",
        port: int = DEFAULT_SHELL_PORT,
        token_file: str | Path | None = None,
        max_clients: int = 8,
        max_line: int = 256,
        rate_per_s: float = 20.0,
        events: EventBus | None = None,
        clock: Callable[[], float] = time.monotonic,
        max_unauthenticated: int = 2,
        auth_timeout_s: float = 10.0,
        idle_timeout_s: float | None = 1800.0,
        max_overflow: int = 8,
        overflow_window_s: float = 2.0,
        guard: AuthGuard | None = None,
        allow_from: tuple[str, ...] = (),
    ) -> None:
        self.host, self.port = host, port
        self.events = events if events is not None else EventBus()
        self.max_clients = max_clients
        self.max_unauthenticated, self.max_overflow = max_unauthenticated, max_overflow
        self.overflow_window_s = overflow_window_s
        self.guard = guard if guard is not None else AuthGuard()
        self._handler, self._token_file, self._clock = handler, token_file, clock
        self._limits = SessionLimits(max_line=max_line, rate_per_s=rate_per_s, auth_timeout_s=auth_timeout_s,
                                     idle_timeout_s=idle_timeout_s)
        self._allowed = [ipaddress.ip_network(net, strict=False) for net in allow_from]
        self._overflow: set[int] = set()
        self._quiet = RateLimitedLog(log)
        self._token: str | None = None
        self._server: asyncio.Server | None = None
        self._sessions: dict[int, Session] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self._next_id = 1
        self.close_grace_s = 2.0  # how long a closing connection may take to flush what it was sent

    @property
    def client_count(self) -> int:
        """Sessions currently connected."""
        return len(self._sessions)

    @property
    def admitted_count(self) -> int:
        """Sessions that hold one of the `max_clients` slots."""
        return sum(s.admitted for s in self._sessions.values())

    def _peer_allowed(self, peername: object) -> bool:
        """Loopback always; else, when shell.allow_from is set, a peer inside one of its subnets."""
        if not self._allowed or not isinstance(peername, tuple):
            return True
        try:
            address = ipaddress.ip_address(peername[0])
        except ValueError:
            return False
        return address.is_loopback or any(address in net for net in self._allowed)

    def _admit(self, session: Session) -> str | None:
        """A pending session authenticated (or, without a token, sent a line): is there a slot?"""
        if self.admitted_count >= self.max_clients:
            return f"too many clients (max {self.max_clients}); try again later (estop still works)"
        self._overflow.discard(session.info.id)
        return None

    def broadcast(self, event: str) -> None:
        """Send `* event` to every client of every transport sharing this server's bus."""
        self.events.broadcast(event)

    async def start(self) -> None:
        """Load the token (if any), bind and start accepting; `.port` is then the bound port."""
        if self._token_file is not None:
            self._token = load_token(self._token_file)
        elif not is_loopback(self.host):
            raise ConfigError(
                f"the shell would listen on {self.host!r} without a token; set a token file (mode 0600) "
                "or listen on 127.0.0.1"
            )
        try:
            self._server = await asyncio.start_server(self._on_connect, self.host, self.port)
        except OSError as exc:
            raise ConfigError(f"cannot listen on {self.host}:{self.port}: {exc}; is another gprbot running?") from exc
        self.port = self._server.sockets[0].getsockname()[1]
        log.info("shell listening on %s:%d (%s)", self.host, self.port, "token" if self._token else "no token")

    async def close(self, grace_s: float = 1.0) -> None:
        """Stop accepting and drop every client: sessions get `grace_s` to finish, then their connections
        are aborted (unsent output discarded: a client that stopped reading must not hold up shutdown)
        and what is left is cancelled."""
        if self._server is not None:
            self._server.close()
        for session in list(self._sessions.values()):
            session.close()
        if self._tasks:
            _, pending = await asyncio.wait(set(self._tasks), timeout=grace_s)
            if pending:
                for session in list(self._sessions.values()):
                    session.abort()
                _, pending = await asyncio.wait(pending, timeout=0.5)
            for task in pending:
                task.cancel()
            await asyncio.gather(*pending, return_exceptions=True)
        if self._server is not None:
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(grace_s):
                    await self._server.wait_closed()
            self._server = None

    async def _on_connect(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        peername = writer.get_extra_info("peername")
        peer = f"{peername[0]}:{peername[1]}" if isinstance(peername, tuple) else str(peername)
        try:
            if not self._peer_allowed(peername):
                self._quiet.log(logging.WARNING, "outside", "shell: refusing %s: not in shell.allow_from", peer)
                writer.write(encode_reply(Reply.failure(ErrorCode.UNAUTHORIZED, "this network may not use the shell")))
                return
            pending = sum(not s.admitted for s in self._sessions.values()) - len(self._overflow)
            if pending < self.max_unauthenticated:
                deadline, overflow = self._limits.auth_timeout_s, False
            elif len(self._overflow) < self.max_overflow:
                deadline, overflow = self.overflow_window_s, True
            else:
                self._quiet.log(logging.WARNING, "refuse", "shell: refusing %s, %d clients already",
                                peer, len(self._sessions))
                text = f"too many clients (max {self.max_clients}); try again later"
                writer.write(encode_reply(Reply.failure(ErrorCode.BUSY, text)))
                with contextlib.suppress(ConnectionError, OSError):
                    async with asyncio.timeout(1.0):
                        await writer.drain()
                return
            info = SessionInfo(self._next_id, "tcp", peer, authenticated=self._token is None)
            self._next_id += 1
            session = Session(
                self._handler, info, reader, writer, self.events,
                token=self._token, limits=self._limits, clock=self._clock,
                admit=self._admit, pending_deadline_s=deadline, guard=self.guard, quiet_log=self._quiet,
            )
            self._sessions[info.id] = session
            if overflow:
                self._overflow.add(info.id)
            self._quiet.log(logging.INFO, "connect", "shell: %s connected (session %d%s)", peer, info.id,
                            ", over quota" if overflow else "")
            try:
                await session.run()
            finally:
                del self._sessions[info.id]
                self._overflow.discard(info.id)
                self._quiet.log(logging.INFO, "connect", "shell: %s disconnected", peer)
        finally:
            writer.close()
            with contextlib.suppress(ConnectionError, OSError, TimeoutError):
                async with asyncio.timeout(self.close_grace_s):  # a client that reads nothing must not hold us
                    await writer.wait_closed()
            if not writer.transport.is_closing() or writer.transport.get_write_buffer_size():
                writer.transport.abort()
            self._tasks.discard(task)


@dataclass
class _SerialLink:
    port: serial.SerialBase
    reader: asyncio.StreamReader
    writer: asyncio.StreamWriter
    read_transport: asyncio.ReadTransport


class SerialShell:
    """The shell on a serial console (physical access: no token). Re-opens the port after a hang-up."""

    def __init__(
        self,
        handler: CommandHandler,
        port_url: str,
        *,
        baudrate: int = 115200,
        events: EventBus | None = None,
        max_line: int = 256,
        rate_per_s: float = 20.0,
        reopen_s: float = 2.0,
    ) -> None:
        self.port_url, self.baudrate, self.reopen_s = port_url, baudrate, reopen_s
        self.events = events if events is not None else EventBus()
        self._handler = handler
        self._limits = SessionLimits(max_line=max_line, rate_per_s=rate_per_s)
        self._task: asyncio.Task[None] | None = None
        self._session: Session | None = None
        self._sessions_started = 0

    async def start(self) -> None:
        """Open the port (DriverError if it cannot be opened now) and serve it until close()."""
        first = await self._open()
        self._task = asyncio.create_task(self._serve(first), name=f"serial-shell-{self.port_url}")

    async def close(self) -> None:
        """Stop serving and close the port."""
        if self._task is None:
            return
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task
        self._task = None

    async def _open(self) -> _SerialLink:
        try:
            port = serial.serial_for_url(self.port_url, baudrate=self.baudrate, timeout=0)
            fd = port.fileno()
        except (serial.SerialException, ValueError, OSError, AttributeError, NotImplementedError) as exc:
            raise DriverError(f"cannot open serial console {self.port_url}: {exc}; check the path") from exc
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader(limit=self._limits.max_line * 4)
        # separate fds: each pipe transport owns and closes its file object
        read_file = os.fdopen(os.dup(fd), "rb", buffering=0)
        write_file = os.fdopen(os.dup(fd), "wb", buffering=0)
        read_transport, _ = await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), read_file)
        write_transport, write_protocol = await loop.connect_write_pipe(
            lambda: asyncio.StreamReaderProtocol(asyncio.StreamReader()), write_file
        )
        writer = asyncio.StreamWriter(write_transport, write_protocol, reader, loop)
        return _SerialLink(port, reader, writer, read_transport)

    async def _serve(self, opened: _SerialLink | None) -> None:
        while True:
            if opened is None:
                try:
                    opened = await self._open()
                except DriverError as exc:
                    log.warning("%s; retrying in %g s", exc, self.reopen_s)
                    await asyncio.sleep(self.reopen_s)
                    continue
            self._sessions_started += 1
            info = SessionInfo(-self._sessions_started, "serial", self.port_url, authenticated=True)
            self._session = Session(self._handler, info, opened.reader, opened.writer, self.events, limits=self._limits)
            try:
                await self._session.run()
            finally:
                self._session.close()
                opened.read_transport.close()
                opened.port.close()
            log.warning("serial console %s hung up; re-opening in %g s", self.port_url, self.reopen_s)
            opened = None
            await asyncio.sleep(self.reopen_s)
