"""One packet-serial line to one or more RoboClaws: one request in flight, timeouts, retries, stops first.

Every exchange discards stale input, writes the packet and feeds the answer to a `ReplyParser`
until it completes, the per-attempt timeout passes or the CRC fails; then it retries. After the
last attempt it raises `LinkError`; the driver decides what a failure means (fault, or a clear
start-up error). Stops take the line ahead of every queued request (`urgent=True`).
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Awaitable, Callable, Sequence
from typing import TypeVar

from gprbot.drivers.motors.protocol import ACK, Request
from gprbot.drivers.motors.replies import Reply, ReplyParser
from gprbot.drivers.serial_port import AsyncSerialPort
from gprbot.errors import DriverError, ProtocolError

T = TypeVar("T")


class LinkError(Exception):
    """A request got no valid answer after every attempt (or the port itself failed)."""

    def __init__(self, text: str, *, timeouts: int = 0, corrupt: int = 0, port_error: bool = False) -> None:
        super().__init__(text)
        self.timeouts = timeouts
        self.corrupt = corrupt
        self.port_error = port_error


class SupersededError(Exception):
    """A queued request was no longer wanted when its turn came (a stop or a fault overtook it)."""


class PriorityLock:
    """A FIFO mutex where urgent acquirers go to the front of the queue (a stop passes every read)."""

    def __init__(self) -> None:
        self._locked = False
        self._waiters: deque[asyncio.Future[None]] = deque()

    async def acquire(self, urgent: bool = False) -> None:
        """Wait for the lock; urgent waiters are served before all normal ones."""
        if not self._locked and not self._waiters:
            self._locked = True
            return
        waiter: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        if urgent:
            self._waiters.appendleft(waiter)
        else:
            self._waiters.append(waiter)
        try:
            await waiter
        except asyncio.CancelledError:
            if waiter.done() and not waiter.cancelled():
                self.release()  # ownership was handed to us just as we were cancelled
            else:
                self._waiters.remove(waiter)
            raise

    def release(self) -> None:
        """Hand the lock to the next waiter, or free it."""
        while self._waiters:
            waiter = self._waiters.popleft()
            if not waiter.done():
                waiter.set_result(None)
                return
        self._locked = False


class PacketBus:
    """The request/reply discipline on one serial line."""

    def __init__(
        self,
        url: str,
        baudrate: int,
        timeout_s: float,
        retries: int,
        on_bad_attempt: Callable[[str], None] = lambda text: None,
    ) -> None:
        self.url = url
        self.port = AsyncSerialPort(url, baudrate)
        self.timeout_s = timeout_s
        self.retries = retries
        self._on_bad_attempt = on_bad_attempt
        self._lock = PriorityLock()

    async def open(self) -> None:
        """Open the serial port (DriverError if it cannot be opened)."""
        await self.port.open()

    def close(self) -> None:
        """Close the serial port."""
        self.port.close()

    async def exchange(
        self, request: Request, *, urgent: bool = False, still_wanted: Callable[[], bool] | None = None
    ) -> Reply:
        """Send `request` and return its decoded reply, retrying; LinkError when all attempts fail.

        `still_wanted` is asked once the line is ours; if it says no, SupersededError is raised unsent.
        """
        await self._lock.acquire(urgent)
        try:
            if still_wanted is not None and not still_wanted():
                raise SupersededError(request.describe())
            return await self._with_retries(request.describe(), lambda: self._attempt(request))
        finally:
            self._lock.release()

    async def stop_all(self, stop_requests: Sequence[Request]) -> None:
        """Send all stop packets back to back (ahead of the queue), then expect one 0xFF per packet.

        Back to back because the failsafe bound counts from the fault, not from the last ack; the
        acks cannot collide on a shared line since each follows its own packet by a packet's length.
        """
        await self._lock.acquire(urgent=True)
        try:
            await self._with_retries("stop", lambda: self._attempt_acks(stop_requests))
        finally:
            self._lock.release()

    def write_unlocked(self, packets: Sequence[Request]) -> None:
        """Fire-and-forget writes for the fault path (the line is already considered broken)."""
        for request in packets:
            try:
                self.port.write(request.encode())
            except DriverError:
                return

    async def _with_retries(self, what: str, attempt: Callable[[], Awaitable[T]]) -> T:
        timeouts = corrupt = 0
        last = ""
        for _ in range(1 + self.retries):
            try:
                return await attempt()
            except TimeoutError:
                timeouts += 1
                last = f"{what}: no reply within {self.timeout_s * 1000:.0f} ms"
            except ProtocolError as exc:
                corrupt += 1
                last = str(exc)
            except DriverError as exc:
                raise LinkError(f"{what} on {self.url}: {exc}", port_error=True) from exc
            self._on_bad_attempt(f"{last} on {self.url}")
        raise LinkError(
            f"{what} on {self.url}: no valid reply after {1 + self.retries} attempts (last: {last})",
            timeouts=timeouts,
            corrupt=corrupt,
        )

    async def _attempt(self, request: Request) -> Reply:
        self.port.discard_input()
        self.port.write(request.encode())
        parser = ReplyParser(request)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.timeout_s
        while True:
            remaining = deadline - loop.time()
            data = await self.port.read(remaining) if remaining > 0 else b""
            if not data:
                raise TimeoutError
            reply = parser.feed(data)
            if reply is not None:
                return reply

    async def _attempt_acks(self, requests: Sequence[Request]) -> None:
        self.port.discard_input()
        for request in requests:
            self.port.write(request.encode())
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.timeout_s
        acks = 0
        while acks < len(requests):
            remaining = deadline - loop.time()
            data = await self.port.read(remaining) if remaining > 0 else b""
            if not data:
                raise TimeoutError
            if any(byte != ACK for byte in data):
                raise ProtocolError(f"stop: expected {len(requests)} acknowledgements 0xFF, got {data.hex()}")
            acks += len(data)
