"""systemd's notify protocol (sd_notify(3)), stdlib only: READY, STATUS, WATCHDOG, STOPPING.

Messages are newline-separated `KEY=value` assignments sent as one datagram to the AF_UNIX socket
named by $NOTIFY_SOCKET (a leading `@` names the abstract namespace). Without $NOTIFY_SOCKET (not
started by systemd with Type=notify) every call is a no-op, so the daemon runs the same by hand.
The watchdog interval comes from $WATCHDOG_USEC, and only applies when $WATCHDOG_PID is unset or
ours (sd_watchdog_enabled(3)).
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

log = logging.getLogger(__name__)


def _socket_address(path: str) -> str | bytes:
    """The connect() address for $NOTIFY_SOCKET: '@name' is the abstract socket '\\0name'."""
    if path.startswith("@"):
        return b"\0" + path[1:].encode()
    return path


def watchdog_interval_s(environ: Mapping[str, str] | None = None) -> float | None:
    """systemd's watchdog timeout in seconds for this process, or None when no watchdog applies."""
    env = os.environ if environ is None else environ
    usec = env.get("WATCHDOG_USEC")
    if not usec:
        return None
    pid = env.get("WATCHDOG_PID")
    if pid and pid.isdigit() and int(pid) != os.getpid():
        return None
    try:
        value = int(usec)
    except ValueError:
        return None
    return value / 1e6 if value > 0 else None


class SdNotifier:
    """Sends notify messages to systemd; silent (and counting nothing) when not under systemd."""

    def __init__(self, socket_path: str | None = None, environ: Mapping[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        self.socket_path = socket_path if socket_path is not None else env.get("NOTIFY_SOCKET") or None
        self.sent: list[str] = []  # every message sent, for status and tests
        self._sock: socket.socket | None = None
        if self.socket_path:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.setblocking(False)

    @property
    def enabled(self) -> bool:
        """Whether a notify socket is configured."""
        return self._sock is not None

    def notify(self, **fields: str) -> bool:
        """Send one datagram of KEY=value lines (e.g. READY="1"); whether it was sent."""
        if self._sock is None or self.socket_path is None:
            return False
        text = "\n".join(f"{key}={value}".replace("\n", " ") for key, value in fields.items())
        try:
            self._sock.sendto(text.encode("utf-8"), _socket_address(self.socket_path))
        except OSError as exc:  # systemd gone or socket full: never fatal to the robot
            log.warning("sd_notify to %s failed: %s", self.socket_path, exc)
            return False
        self.sent.append(text)
        return True

    def ready(self, status: str = "") -> bool:
        """READY=1 (with a STATUS line): the daemon is up."""
        return self.notify(READY="1", STATUS=status) if status else self.notify(READY="1")

    def status(self, text: str) -> bool:
        """STATUS=text, shown by `systemctl status`."""
        return self.notify(STATUS=text)

    def watchdog(self) -> bool:
        """WATCHDOG=1: the supervisor loop is alive and healthy."""
        return self.notify(WATCHDOG="1")

    def stopping(self, status: str = "") -> bool:
        """STOPPING=1: shutdown has begun."""
        return self.notify(STOPPING="1", STATUS=status) if status else self.notify(STOPPING="1")

    def close(self) -> None:
        """Close the socket."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
