"""What the shell needs from the robot: the CommandHandler interface, session info, the event bus."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Protocol

from gprbot.shell.commands import Jog, Reset, Status, Stop, SurveyControl, SurveyStart
from gprbot.shell.protocol import Reply

log = logging.getLogger(__name__)

RobotCommand = Status | Jog | Stop | Reset | SurveyStart | SurveyControl
"""The commands the shell passes to the handler; help, runs, files, pull and auth it answers itself."""


@dataclass
class SessionInfo:
    """One connected client (or the serial console) as the handler sees it."""

    id: int
    transport: Literal["tcp", "serial", "web"]
    peer: str
    authenticated: bool


class CommandHandler(Protocol):
    """The robot side of the shell, implemented by the daemon (and by FakeHandler in tests)."""

    async def handle(self, command: RobotCommand, session: SessionInfo) -> Reply:
        """Execute one command and return promptly (accept, don't wait for the motion to finish)."""
        ...

    async def estop(self, session: SessionInfo) -> Reply:
        """Cut the motors now; called at once, ahead of any queued command, for any client."""
        ...

    def runs_dir(self) -> Path:
        """The directory holding one sub-directory per run (what `runs`/`files`/`pull` serve)."""
        ...


class EventBus:
    """Fan-out of `*` event lines to every connected session; the daemon calls `broadcast`."""

    def __init__(self) -> None:
        self._subscribers: dict[int, Callable[[str], None]] = {}
        self._next_id = 0

    def subscribe(self, deliver: Callable[[str], None]) -> Callable[[], None]:
        """Register a session's event sink; returns the function that unregisters it."""
        key = self._next_id
        self._next_id += 1
        self._subscribers[key] = deliver

        def unsubscribe() -> None:
            self._subscribers.pop(key, None)

        return unsubscribe

    def broadcast(self, event: str) -> None:
        """Send `* event` to every session (a slow session is dropped rather than delaying others)."""
        for deliver in list(self._subscribers.values()):
            try:
                deliver(event)
            except Exception:  # one broken session must not stop the others' events
                log.exception("event delivery failed")

    @property
    def subscriber_count(self) -> int:
        """How many sessions currently receive events."""
        return len(self._subscribers)
