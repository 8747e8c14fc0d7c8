"""One packet-serial line to one or more RoboClaws: one request in flight, timeouts, retries, stops first.

Every exchange discards stale input, writes the packet and feeds the answer to a `ReplyParser`
until it completes, the per-attempt timeout passes or the CRC fails; then it retries. After the
last attempt it raises `LinkError`; the driver decides what a failure means (fault, or a clear
start-up error). Stops take the line ahead of every queued request (`urgent=True`).

A timeout counts only time in which the loop was listening: a wait that ends past its deadline may
have been spent with the loop busy elsewhere (a loaded machine, a long callback), and the reply may be
queued right behind us — with an emulator on the same loop, not even written yet. So each attempt
listens a short grace past its deadline, and again while those graces end late (bounded), instead of
calling a live controller silent; on a loop that runs on time a silent controller is still detected
after (1 + retries) × timeout × (1 + GRACE_FRACTION), which `safety` holds within the stop bound.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Awaitable, Callable, Sequence
from typing import TypeVar

from gprbot.drivers.motors.protocol import ACK, Request
from gprbot.drivers.motors.replies import Reply, ReplyParser
from gprbot.drivers.serial_port import AsyncSerialPort
from gprbot.errors import DriverError, ProtocolError

T = TypeVar("T")
LATE_S = 0.003  # a wait that ends this long past its deadline was not listening (epoll rounds up to 1 ms)
MAX_LATE_LISTENS = 2  # more graces an attempt gets when its waits end late; bounds a starved attempt
GRACE_FRACTION = 0.25  # each attempt listens this fraction of its timeout past the deadline (see _listener)


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
            elif waiter in self._waiters:  # release() may already have popped it (it skips cancelled ones)
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
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.url = url
        self.port = AsyncSerialPort(url, baudrate)
        self.timeout_s = timeout_s
        self.retries = retries
        self._on_bad_attempt = on_bad_attempt
        self._clock = clock
        self._lock = PriorityLock()
        self.late_listens = 0  # waits that ended late and were listened again (a busy loop, not the device)

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
        return (await self.exchange_timed(request, urgent=urgent, still_wanted=still_wanted))[0]

    async def exchange_timed(
        self, request: Request, *, urgent: bool = False, still_wanted: Callable[[], bool] | None = None
    ) -> tuple[Reply, float]:
        """`exchange`, with the clock time at which the answered attempt's packet was written.

        The controller samples what it reports when the packet reaches it, so this — not when the loop
        got round to the reply — is the reading's time."""
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

    async def _attempt(self, request: Request) -> tuple[Reply, float]:
        self.port.discard_input()
        self.port.write(request.encode())
        sent = self._clock()
        parser = ReplyParser(request)
        listen = self._listener()
        while True:
            reply = parser.feed(await listen())
            if reply is not None:
                return reply, sent

    async def _attempt_acks(self, requests: Sequence[Request]) -> None:
        self.port.discard_input()
        for request in requests:
            self.port.write(request.encode())
        listen = self._listener()
        acks = 0
        while acks < len(requests):
            data = await listen()
            if any(byte != ACK for byte in data):
                raise ProtocolError(f"stop: expected {len(requests)} acknowledgements 0xFF, got {data.hex()}")
            acks += len(data)

    def _listener(self) -> Callable[[], Awaitable[bytes]]:
        """Reads for one attempt, sharing its deadline; TimeoutError once the device had its time in silence.

        Its time ends with a short grace listen past the deadline: a reply can be on its way through
        the line (a pty's or USB's delivery) or queued behind us in a busy loop pass, and with an
        emulator on this loop even its writing waits for a pass. A grace that itself ends late (the
        loop still busy) is followed by another, at most `MAX_LATE_LISTENS` more."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.timeout_s
        grace_s = GRACE_FRACTION * self.timeout_s
        graces = 0

        async def listen() -> bytes:
            nonlocal deadline, graces
            while True:
                remaining = deadline - loop.time()
                data = await self.port.read(remaining) if remaining > 0 else b""
                if data:
                    return data
                late = loop.time() - deadline > LATE_S
                if graces == 0 or (late and graces <= MAX_LATE_LISTENS):
                    graces += 1
                    self.late_listens += graces > 1
                    deadline = loop.time() + grace_s
                    continue
                raise TimeoutError

        return listen
