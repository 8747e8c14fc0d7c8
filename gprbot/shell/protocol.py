"""The shell's line protocol, sans-IO: bytes → lines on the server, replies/events → bytes, and back on the client.

Wire format (UTF-8, lines end with `\\n`; a `\\r` before it is dropped):
  client → server  one command per line
  server → client  a reply to each line: optional body lines `= …`, then exactly one `ok [text]` or
                   `error <code> <text>` line; `ok pull <bytes> <sha256>` is followed by exactly
                   <bytes> raw bytes. Events are lines `* <text>`, never inside a reply.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from gprbot.errors import ProtocolError
from gprbot.shell.commands import ErrorCode

_PULL_HEADER = re.compile(r"pull (\d{1,15}) ([0-9a-f]{64})")


@dataclass(frozen=True)
class Reply:
    """The answer to one command: ok or an error code, a one-line text and optional body lines."""

    ok: bool
    text: str = ""
    code: ErrorCode | None = None
    body: tuple[str, ...] = ()

    @classmethod
    def success(cls, text: str = "", body: tuple[str, ...] | list[str] = ()) -> Reply:
        """An `ok` reply."""
        return cls(True, text, None, tuple(body))

    @classmethod
    def failure(cls, code: ErrorCode, text: str) -> Reply:
        """An `error <code> <text>` reply."""
        return cls(False, text, code)


def _one_line(text: str) -> str:
    return text.replace("\r", " ").replace("\n", " ")


def encode_reply(reply: Reply) -> bytes:
    """The bytes of a reply: its body lines, then the ok/error line."""
    lines = [f"= {_one_line(item)}" for item in reply.body]
    if reply.ok:
        lines.append(f"ok {_one_line(reply.text)}" if reply.text else "ok")
    else:
        lines.append(f"error {reply.code or ErrorCode.INTERNAL} {_one_line(reply.text)}".rstrip())
    return ("\n".join(lines) + "\n").encode("utf-8", "replace")


def encode_event(text: str) -> bytes:
    """The bytes of an asynchronous event line `* text`."""
    return f"* {_one_line(text)}\n".encode("utf-8", "replace")


@dataclass(frozen=True)
class LineReceived:
    """A complete, decoded command line (line ending removed)."""

    text: str


@dataclass(frozen=True)
class LineRejected:
    """A line that cannot be a command (too long, not UTF-8); it still gets one error reply."""

    code: ErrorCode
    text: str


class LineSplitter:
    """Server side: feed received bytes, get one LineReceived or LineRejected per line sent.

    A line longer than `max_line` bytes (line ending excluded) is skipped up to its newline, so the
    buffer never grows beyond `max_line` + 1, and rejected once when that newline arrives.
    """

    def __init__(self, max_line: int = 256) -> None:
        self.max_line = max_line
        self._buffer = bytearray()
        self._skipping = False

    def feed(self, data: bytes) -> list[LineReceived | LineRejected]:
        """Consume `data`; return the complete lines it finishes, in order."""
        out: list[LineReceived | LineRejected] = []
        start = 0
        while start < len(data):
            newline = data.find(b"\n", start)
            end = len(data) if newline < 0 else newline
            if not self._skipping:
                self._buffer += data[start:end]
                if len(self._buffer) > self.max_line + 1:  # +1: the line's last byte may be a CRLF's CR
                    self._buffer.clear()
                    self._skipping = True
            if newline < 0:
                break
            if self._skipping:
                self._skipping = False
                out.append(LineRejected(ErrorCode.TOO_LONG, f"line longer than {self.max_line} bytes; ignored"))
            else:
                out.append(self._decode(bytes(self._buffer)))
            self._buffer.clear()
            start = newline + 1
        return out

    def _decode(self, raw: bytes) -> LineReceived | LineRejected:
        if raw.endswith(b"\r"):
            raw = raw[:-1]
        if len(raw) > self.max_line:
            return LineRejected(ErrorCode.TOO_LONG, f"line longer than {self.max_line} bytes; ignored")
        try:
            return LineReceived(raw.decode("utf-8"))
        except UnicodeDecodeError:
            return LineRejected(ErrorCode.BAD_COMMAND, "line is not valid UTF-8")


@dataclass(frozen=True)
class ServerReply:
    """Client side: one complete reply; `payload_size` is set for `ok pull` (raw bytes follow)."""

    ok: bool
    code: str | None
    text: str
    body: tuple[str, ...]
    payload_size: int | None = None
    payload_sha256: str | None = None


@dataclass(frozen=True)
class ServerEvent:
    """Client side: an asynchronous `*` event."""

    text: str


@dataclass(frozen=True)
class PayloadChunk:
    """Client side: raw bytes of a pulled file; `last` on the chunk that completes it."""

    data: bytes
    last: bool


ClientItem = ServerReply | ServerEvent | PayloadChunk


class ReplyReader:
    """Client side: feed bytes from the server, get replies, events and payload chunks in order."""

    def __init__(self, max_line: int = 65536) -> None:
        self.max_line = max_line
        self._buffer = bytearray()
        self._body: list[str] = []
        self._payload_left = 0

    def feed(self, data: bytes) -> list[ClientItem]:
        """Consume `data`; raises ProtocolError if the server breaks the format."""
        out: list[ClientItem] = []
        self._buffer += data
        while self._buffer:
            if self._payload_left:
                take = min(self._payload_left, len(self._buffer))
                self._payload_left -= take
                out.append(PayloadChunk(bytes(self._buffer[:take]), self._payload_left == 0))
                del self._buffer[:take]
                continue
            newline = self._buffer.find(b"\n")
            if newline < 0:
                if len(self._buffer) > self.max_line:
                    raise ProtocolError(f"server sent a line longer than {self.max_line} bytes; is it a gprbot shell?")
                break
            raw = bytes(self._buffer[:newline]).rstrip(b"\r")
            del self._buffer[: newline + 1]
            out.extend(self._line(raw.decode("utf-8", "replace")))
        return out

    def _line(self, line: str) -> list[ClientItem]:
        if line.startswith("* ") or line == "*":
            return [ServerEvent(line[2:])]
        if line.startswith("= ") or line == "=":
            self._body.append(line[2:])
            return []
        body, self._body = tuple(self._body), []
        if line == "ok" or line.startswith("ok "):
            text = line[3:]
            header = _PULL_HEADER.fullmatch(text)
            if header is None:
                return [ServerReply(True, None, text, body)]
            size = int(header.group(1))
            self._payload_left = size
            reply = ServerReply(True, None, text, body, size, header.group(2))
            return [reply, PayloadChunk(b"", True)] if size == 0 else [reply]
        if line.startswith("error "):
            code, _, text = line[6:].partition(" ")
            return [ServerReply(False, code, text, body)]
        raise ProtocolError(f"unexpected line from the server: {line[:80]!r}; is it a gprbot shell?")
