"""Serve a byte handler on a pseudo-terminal pair so that a driver opens it like a USB serial device.

The driver opens the slave side (or a stable symlink to it, like /dev/serial/by-id/...) with
pyserial; the handler sees the bytes the driver writes and its return value is written back.
`close()` hangs the line up — the driver's next read fails as it does when a USB cable is pulled.

The handler runs on the asyncio loop by default, or — `threaded=True`, as the simulated robot serves
its controllers — in a thread of its own, so that the emulated device answers within a millisecond
whatever the loop is doing, as a real controller on USB does (on the loop, a busy loop delays the
device's answer itself, which no real device does).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import select
import threading
import tty
from collections.abc import Callable
from pathlib import Path

from gprbot.errors import DriverError


class PtyLink:
    """A pty whose master end is driven by `handler(bytes) -> reply bytes` on the loop (or its own thread)."""

    def __init__(self, handler: Callable[[bytes], bytes], link_path: str | Path | None = None, *,
                 threaded: bool = False) -> None:
        self._handler = handler
        self._threaded = threaded
        self._thread: threading.Thread | None = None
        self._wake: tuple[int, int] | None = None  # a pipe that tells the thread to stop
        self._link_path = Path(link_path) if link_path is not None else None
        self._master: int | None = None
        self._slave: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self.slave_name: str | None = None
        self.bytes_in = 0
        self.bytes_out = 0

    @property
    def is_open(self) -> bool:
        """True while the pty exists (the 'cable' is plugged in)."""
        return self._master is not None

    def open(self) -> str:
        """Create the pty, start serving it on the running loop; return the path a driver should open."""
        if self._master is not None:
            raise DriverError("pty link already open; close() it first")
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line-ending translation before the driver configures it
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self.slave_name = os.ttyname(slave)
        if self._threaded:
            self._wake = os.pipe()
            self._thread = threading.Thread(target=self._serve, args=(master, self._wake[0]),
                                            name="pty-link", daemon=True)
            self._thread.start()
        else:
            self._loop = asyncio.get_running_loop()
            self._loop.add_reader(master, self._on_readable)
        if self._link_path is None:
            return self.slave_name
        tmp = self._link_path.with_name(self._link_path.name + ".new")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        os.symlink(self.slave_name, tmp)
        os.replace(tmp, self._link_path)  # atomic, as udev re-creates /dev/serial/by-id links
        return str(self._link_path)

    def write(self, data: bytes) -> None:
        """Send bytes to the driver (dropped silently when unplugged, like a dead cable)."""
        if self._master is None or not data:
            return
        with contextlib.suppress(OSError):  # the driver stopped reading: a real line drops bytes too
            self.bytes_out += os.write(self._master, data)

    def close(self) -> None:
        """Hang up: remove the reader, close both ends and the symlink."""
        if self._master is None:
            return
        if self._thread is not None and self._wake is not None:
            os.write(self._wake[1], b"x")
            self._thread.join()
            for end in self._wake:
                os.close(end)
            self._thread, self._wake = None, None
        elif self._loop is not None and not self._loop.is_closed():
            self._loop.remove_reader(self._master)
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None
        if self._link_path is not None:
            with contextlib.suppress(FileNotFoundError):
                self._link_path.unlink()

    def _serve(self, master: int, wake: int) -> None:
        """The link's thread: answer what arrives on the master end until woken to stop."""
        while True:
            readable, _, _ = select.select([master, wake], [], [])
            if wake in readable:
                return
            self._on_readable()

    def _on_readable(self) -> None:
        if self._master is None:
            return
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError:
            return  # EIO while no slave fd is open; we hold one, so this is transient
        self.bytes_in += len(data)
        self.write(self._handler(data))
