"""The shell's command grammar: one text line → one typed, validated Command (or a CommandError).

Tokens are split like a POSIX shell (`shlex`), so a file name with spaces can be quoted. The grammar
checks syntax and plain ranges only; the robot's own limits (top speed, slab size) are the handler's.
"""

from __future__ import annotations

import math
import re
import shlex
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum


class ErrorCode(StrEnum):
    """The codes of `error <code> <text>` replies."""

    BAD_COMMAND = "bad_command"
    BAD_ARGUMENT = "bad_argument"
    BUSY = "busy"
    ESTOPPED = "estopped"
    NOT_FOUND = "not_found"
    UNAUTHORIZED = "unauthorized"
    TOO_LONG = "too_long"
    RATE_LIMITED = "rate_limited"
    INTERNAL = "internal"


class CommandError(Exception):
    """A line that is not a valid command; becomes `error <code> <text>` and the session goes on."""

    def __init__(self, code: ErrorCode, text: str) -> None:
        super().__init__(f"{code} {text}")
        self.code = code
        self.text = text


@dataclass(frozen=True)
class Empty:
    """A blank line: answered `ok` (a cheap ping)."""


@dataclass(frozen=True)
class Help:
    """`help [COMMAND]`."""

    topic: str | None = None


@dataclass(frozen=True)
class Status:
    """`status`: the robot's state, one `= key value` body line per item."""


@dataclass(frozen=True)
class Jog:
    """`jog VX VY SECONDS`: drive at (vx, vy) m/s in the robot frame for a bounded time."""

    vx_m_s: float
    vy_m_s: float
    seconds: float


@dataclass(frozen=True)
class Stop:
    """`stop`: a controlled stop (ramps down, keeps the survey resumable)."""


@dataclass(frozen=True)
class Estop:
    """`estop`: cut the motors now; accepted from any client, authenticated or not."""


@dataclass(frozen=True)
class Reset:
    """`reset`: clear an e-stop or a fault once the operator has checked the robot."""


@dataclass(frozen=True)
class SurveyStart:
    """`survey start [lines=N] [spacing=M] [length=L] [speed=V]`; None = the configured default."""

    lines: int | None = None
    spacing_m: float | None = None
    length_m: float | None = None
    speed_m_s: float | None = None


@dataclass(frozen=True)
class SurveyControl:
    """`survey pause|resume|abort`."""

    action: str


@dataclass(frozen=True)
class Runs:
    """`runs`: the run directories, newest first."""


@dataclass(frozen=True)
class Files:
    """`files RUN`: the files of one run with their sizes."""

    run: str


@dataclass(frozen=True)
class Pull:
    """`pull RUN FILE`: reply `ok pull <bytes> <sha256>` then exactly that many raw bytes."""

    run: str
    file: str


@dataclass(frozen=True)
class Auth:
    """`auth TOKEN`: `token` as split like a shell word, `raw` the rest of the line as typed."""

    token: str
    raw: str = field(default="", compare=False)


Command = Empty | Help | Status | Jog | Stop | Estop | Reset | SurveyStart | SurveyControl | Runs | Files | Pull | Auth

MAX_JOG_SECONDS = 30.0
MAX_SPEED_M_S = 5.0
MAX_SURVEY_LINES = 1000
SURVEY_ACTIONS = ("pause", "resume", "abort")
_RUN_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+=@-]{0,127}")

HELP: dict[str, str] = {
    "help": "help [COMMAND]            this text, or one command's",
    "status": "status                    robot state: mode, pose, survey progress, driver health",
    "jog": "jog VX VY SECONDS         drive at VX, VY m/s (robot frame) for SECONDS (≤ 30), heading held",
    "stop": "stop                      controlled stop; a survey can be resumed",
    "estop": "estop                     emergency stop: motors off now (allowed without auth)",
    "reset": "reset                     clear an e-stop or fault after checking the robot",
    "survey": "survey start lines=N spacing=M length=L speed=V | survey pause|resume|abort",
    "runs": "runs                      list the run directories",
    "files": "files RUN                 list a run's files with their sizes",
    "pull": "pull RUN FILE             ok pull <bytes> <sha256>, then the file's raw bytes",
    "auth": "auth TOKEN                authenticate (required when the shell listens beyond loopback)",
}


def help_lines(topic: str | None) -> list[str]:
    """The help body: every command's line, or one command's; CommandError for an unknown topic."""
    if topic is None:
        return list(HELP.values())
    if topic not in HELP:
        raise CommandError(ErrorCode.NOT_FOUND, f"no command {topic!r}; try `help`")
    return [HELP[topic]]


def parse_command(line: str) -> Command:
    """Parse one line (without its line ending) into a Command; raises CommandError if it is invalid."""
    if any((ord(ch) < 32 and ch != "\t") or ord(ch) == 127 for ch in line):
        raise CommandError(ErrorCode.BAD_COMMAND, "control characters are not allowed in a command")
    verb, _, rest = line.strip().partition(" ")
    if verb.lower() == "auth" and rest.strip():
        # A token may hold quotes or backslashes: our client quotes it, a person typing into nc does not.
        raw = rest.strip()
        try:
            words = shlex.split(raw)
        except ValueError:
            words = []
        return Auth(words[0] if len(words) == 1 else raw, raw)
    try:
        tokens = shlex.split(line)
    except ValueError as exc:
        raise CommandError(ErrorCode.BAD_COMMAND, f"cannot split the line: {exc}") from exc
    if not tokens:
        return Empty()
    verb, args = tokens[0].lower(), tokens[1:]
    parser = _PARSERS.get(verb)
    if parser is None:
        raise CommandError(ErrorCode.BAD_COMMAND, f"unknown command {_clip(verb)!r}; try `help`")
    return parser(args)


def _clip(text: str, limit: int = 40) -> str:
    return text if len(text) <= limit else text[:limit] + "…"


def _arity(verb: str, args: list[str], count: int) -> None:
    if len(args) != count:
        raise CommandError(ErrorCode.BAD_ARGUMENT, f"{verb} takes {count} argument(s), got {len(args)}: {HELP[verb]}")


def _number(name: str, text: str, low: float, high: float, *, open_low: bool = False) -> float:
    try:
        value = float(text)
    except ValueError:
        raise CommandError(ErrorCode.BAD_ARGUMENT, f"{name} must be a number, got {_clip(text)!r}") from None
    too_low = value <= low if open_low else value < low
    if not math.isfinite(value) or too_low or value > high:
        bound = "(" if open_low else "["
        raise CommandError(ErrorCode.BAD_ARGUMENT, f"{name} must be in {bound}{low:g}, {high:g}], got {_clip(text)}")
    return value


def _run_name(text: str) -> str:
    if not _RUN_NAME.fullmatch(text) or text in (".", ".."):
        raise CommandError(ErrorCode.BAD_ARGUMENT, f"{_clip(text)!r} is not a run name (letters, digits, . _ - + = @)")
    return text


def _relative_file(text: str) -> str:
    parts = text.split("/")
    if text.startswith("/") or "\\" in text or any(p in ("", ".", "..") for p in parts):
        raise CommandError(ErrorCode.BAD_ARGUMENT, f"{_clip(text)!r} must be a plain path inside the run (no '..')")
    return text


def _no_args(factory: Callable[[], Command], verb: str) -> Callable[[list[str]], Command]:
    def parse(args: list[str]) -> Command:
        _arity(verb, args, 0)
        return factory()

    return parse


def _parse_help(args: list[str]) -> Command:
    if len(args) > 1:
        raise CommandError(ErrorCode.BAD_ARGUMENT, f"help takes at most one argument: {HELP['help']}")
    return Help(args[0].lower() if args else None)


def _parse_jog(args: list[str]) -> Command:
    _arity("jog", args, 3)
    return Jog(
        _number("VX", args[0], -MAX_SPEED_M_S, MAX_SPEED_M_S),
        _number("VY", args[1], -MAX_SPEED_M_S, MAX_SPEED_M_S),
        _number("SECONDS", args[2], 0.0, MAX_JOG_SECONDS, open_low=True),
    )


def _parse_survey(args: list[str]) -> Command:
    if not args:
        raise CommandError(ErrorCode.BAD_ARGUMENT, f"survey needs an action: {HELP['survey']}")
    action, rest = args[0].lower(), args[1:]
    if action in SURVEY_ACTIONS:
        _arity("survey", rest, 0)
        return SurveyControl(action)
    if action != "start":
        raise CommandError(ErrorCode.BAD_ARGUMENT, f"unknown survey action {_clip(action)!r}: {HELP['survey']}")
    values: dict[str, str] = {}
    for item in rest:
        key, sep, value = item.partition("=")
        if not sep or key not in ("lines", "spacing", "length", "speed"):
            expected = "lines=, spacing=, length= or speed="
            raise CommandError(ErrorCode.BAD_ARGUMENT, f"expected {expected}, got {_clip(item)!r}")
        if key in values:
            raise CommandError(ErrorCode.BAD_ARGUMENT, f"{key}= given twice")
        values[key] = value
    lines = None
    if "lines" in values:
        if not values["lines"].isdigit():
            raise CommandError(ErrorCode.BAD_ARGUMENT, f"lines must be a whole number, got {_clip(values['lines'])!r}")
        lines = int(values["lines"])
        if not 1 <= lines <= MAX_SURVEY_LINES:
            raise CommandError(ErrorCode.BAD_ARGUMENT, f"lines must be in [1, {MAX_SURVEY_LINES}], got {lines}")

    def optional(key: str, high: float) -> float | None:
        return _number(key, values[key], 0.0, high, open_low=True) if key in values else None

    return SurveyStart(lines, optional("spacing", 100.0), optional("length", 1000.0), optional("speed", MAX_SPEED_M_S))


def _parse_files(args: list[str]) -> Command:
    _arity("files", args, 1)
    return Files(_run_name(args[0]))


def _parse_pull(args: list[str]) -> Command:
    _arity("pull", args, 2)
    return Pull(_run_name(args[0]), _relative_file(args[1]))


def _parse_auth(args: list[str]) -> Command:
    _arity("auth", args, 1)
    return Auth(args[0])


_PARSERS: dict[str, Callable[[list[str]], Command]] = {
    "help": _parse_help,
    "status": _no_args(Status, "status"),
    "jog": _parse_jog,
    "stop": _no_args(Stop, "stop"),
    "estop": _no_args(Estop, "estop"),
    "reset": _no_args(Reset, "reset"),
    "survey": _parse_survey,
    "runs": _no_args(Runs, "runs"),
    "files": _parse_files,
    "pull": _parse_pull,
    "auth": _parse_auth,
}
