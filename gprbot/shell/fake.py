"""A stand-in robot for the shell's tests and for trying the client without a robot."""

from __future__ import annotations

import asyncio
from pathlib import Path

from gprbot.shell.commands import ErrorCode, Jog, Reset, Status, Stop, SurveyControl, SurveyStart
from gprbot.shell.handler import EventBus, RobotCommand, SessionInfo
from gprbot.shell.protocol import Reply


class FakeHandler:
    """Records every command; e-stop latches until `reset`; `gate` (if set) holds `handle` until opened."""

    def __init__(self, runs_dir: Path, events: EventBus | None = None) -> None:
        self._runs_dir = runs_dir
        self.events = events
        self.handled: list[tuple[RobotCommand, int]] = []
        self.estops: list[int] = []
        self.estopped = False
        self.gate: asyncio.Event | None = None

    async def handle(self, command: RobotCommand, session: SessionInfo) -> Reply:
        """Answer like the robot would, without moving anything."""
        if self.gate is not None:
            await self.gate.wait()
        self.handled.append((command, session.id))
        if isinstance(command, Status):
            state = "estopped" if self.estopped else "idle"
            return Reply.success("status", [f"mode {state}", f"commands {len(self.handled)}"])
        if isinstance(command, Reset):
            self.estopped = False
            return Reply.success("reset")
        if isinstance(command, Stop):
            return Reply.success("stop")
        if self.estopped:
            return Reply.failure(ErrorCode.ESTOPPED, "e-stop is latched; check the robot, then `reset`")
        if isinstance(command, Jog):
            return Reply.success(f"jog {command.vx_m_s:g} {command.vy_m_s:g} {command.seconds:g}")
        if isinstance(command, SurveyStart):
            if self.events is not None:
                self.events.broadcast("survey started")
            return Reply.success(f"survey start lines={command.lines}")
        assert isinstance(command, SurveyControl)
        return Reply.success(f"survey {command.action}")

    async def estop(self, session: SessionInfo) -> Reply:
        """Latch the e-stop and tell every client."""
        self.estopped = True
        self.estops.append(session.id)
        if self.events is not None:
            self.events.broadcast("estop")
        return Reply.success("estop")

    def runs_dir(self) -> Path:
        """The directory of runs this fake serves."""
        return self._runs_dir
