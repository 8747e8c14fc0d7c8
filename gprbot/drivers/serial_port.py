"""A pyserial port driven by the asyncio loop: non-blocking, read through `add_reader` on its fd.

Any `serial_for_url` URL with a file descriptor works: /dev/ttyACM0, /dev/serial/by-id/..., a pty in
tests. pyserial's `loop://` has none (use a pty instead). A hang-up (cable pulled) surfaces as a
DriverError from the next `read()`/`write()`, never as a silent stall.
"""

from __future__ import annotations

import asyncio
import contextlib

import serial

from gprbot.errors import DriverError


class AsyncSerialPort:
    """One serial port; a single consumer reads with `read(timeout)`, anyone may `write`."""

    def __init__(self, url: str, baudrate: int) -> None:
        self.url = url
        self.baudrate = baudrate
        self._serial: serial.SerialBase | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._fd: int | None = None
        self._buffer = bytearray()
        self._waiter: asyncio.Future[None] | None = None
        self._failure: str | None = None

    @property
    def is_open(self) -> bool:
        """True between a successful open() and close() (even if the line has since failed)."""
        return self._serial is not None

    async def open(self) -> None:
        """Open the port in non-blocking mode and start reading it on the running loop."""
        try:
            port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0, write_timeout=0)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise DriverError(f"cannot open serial port {self.url}: {exc}; check the cable and the path") from exc
        try:
            fd = port.fileno()
        except (AttributeError, NotImplementedError, serial.SerialException) as exc:
            port.close()
            raise DriverError(
                f"serial port {self.url} has no file descriptor and cannot be used with asyncio "
                "(pyserial's loop:// cannot; use a pty or a real device)"
            ) from exc
        self._serial, self._fd, self._failure = port, fd, None
        self._buffer.clear()
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(fd, self._on_readable)

    def write(self, data: bytes) -> None:
        """Queue bytes for sending now; raises DriverError if the line is down or the buffer is full."""
        port = self._require_open()
        try:
            written = port.write(data)
        except serial.SerialException as exc:
            self._fail(f"write failed: {exc}")
            raise DriverError(f"serial port {self.url}: {self._failure}") from exc
        if written != len(data):
            raise DriverError(f"serial port {self.url}: only {written} of {len(data)} bytes sent (output full)")

    async def read(self, timeout_s: float) -> bytes:
        """Everything received so far, waiting up to `timeout_s` for at least one byte (b'' on timeout)."""
        self._require_open()
        if not self._buffer and self._failure is None:
            assert self._loop is not None
            self._waiter = self._loop.create_future()
            # asyncio.timeout, not wait_for: on Python 3.11 wait_for can swallow a cancellation.
            try:
                async with asyncio.timeout(timeout_s):
                    await asyncio.shield(self._waiter)
            except TimeoutError:
                pass
            finally:
                self._waiter = None
        if self._buffer:
            data = bytes(self._buffer)
            self._buffer.clear()
            return data
        if self._failure is not None:
            raise DriverError(f"serial port {self.url}: {self._failure} (device unplugged or reset?)")
        return b""

    def discard_input(self) -> int:
        """Drop bytes received but not yet read (stale replies, noise); returns how many."""
        count = len(self._buffer)
        self._buffer.clear()
        return count

    def close(self) -> None:
        """Stop reading and close the port (safe to call twice)."""
        if self._fd is not None and self._loop is not None and not self._loop.is_closed():
            self._loop.remove_reader(self._fd)
        if self._serial is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                self._serial.close()
        self._serial, self._fd = None, None
        self._wake()

    def _require_open(self) -> serial.SerialBase:
        if self._serial is None:
            raise DriverError(f"serial port {self.url} is not open")
        return self._serial

    def _on_readable(self) -> None:
        if self._serial is None:
            return
        try:
            data = self._serial.read(4096)
        except serial.SerialException as exc:
            self._fail(str(exc))
            return
        if data:
            self._buffer += data
            self._wake()

    def _fail(self, text: str) -> None:
        if self._failure is None:
            self._failure = text
        if self._fd is not None and self._loop is not None:
            self._loop.remove_reader(self._fd)  # a hung-up fd stays readable forever
        self._wake()

    def _wake(self) -> None:
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_result(None)
