"""Reading a run log back: header, records in order across segments, end marker, torn-tail detection.

Damage is handled by one rule: a record whose frame fails its check is skipped (and counted) only when
resynchronisation is certain — its length field leads exactly to the end of a segment that has a
successor, or to a frame that checks out; anything else stops reading there (`torn`), with the segment,
byte offset and a note. Everything before the damage stays readable.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack

from gprbot.errors import DataFormatError, ProtocolError
from gprbot.messages import MESSAGE_TYPES, decode
from gprbot.runlog import (
    FORMAT,
    FRAME_HEADER,
    KIND_END,
    KIND_HEADER,
    KIND_MESSAGE,
    MAGIC,
    MAX_RECORD_BYTES,
    RECEIVE_TIME,
    frame_crc,
    segment_path,
)


@dataclass(frozen=True)
class LogRecord:
    """One message of the log with its receive time and where it lies (segment index, byte offset)."""

    t_received: float
    message: Any
    segment: int
    offset: int


@dataclass(frozen=True)
class UndecodedMessage:
    """A message whose type is not registered in this process (import its module to decode it)."""

    type_name: str
    payload: bytes


class RunLogReader:
    """Reads a run directory's log; `header` is read at once, the rest on iteration."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = Path(run_dir)
        self.segments = _segment_paths(self.run_dir)
        self.ended = False
        self.summary: dict[str, Any] | None = None
        self.torn = False
        self.torn_segment: int | None = None
        self.torn_offset: int | None = None
        self.note = ""
        self.skipped = 0
        self.undecoded = 0
        self._scanned = False
        first = next(self._frames(), None)
        if first is None or first[:2] != (0, 0) or first[2][:1] != KIND_HEADER:
            why = self.note or "no header"
            raise DataFormatError(f"{self.segments[0]} does not start with a run log header ({why})")
        try:
            header = msgpack.unpackb(first[2][1:], raw=False)
        except (ValueError, msgpack.UnpackException) as exc:
            raise DataFormatError(f"{self.segments[0]}: the header record is unreadable ({exc})") from exc
        if not isinstance(header, dict) or header.get("format") != FORMAT:
            raise DataFormatError(f"{self.segments[0]} is not a {FORMAT} file")
        self.header: dict[str, Any] = header
        self._reset()

    def __iter__(self) -> Iterator[LogRecord]:
        """Every message record in log order (decoded; unregistered types as UndecodedMessage)."""
        self._reset()
        for segment, offset, payload in self._frames():
            kind = payload[:1]
            if self.ended:
                self.skipped += 1
                self._note(f"a record after the end marker at {self._where(segment, offset)}; skipped")
            elif kind == KIND_MESSAGE:
                record = self._decode(segment, offset, payload)
                if record is not None:
                    yield record
            elif kind == KIND_END:
                self._read_end(payload)
            elif kind != KIND_HEADER or (segment, offset) != (0, 0):
                self._note(f"unknown record kind {kind!r} at {self._where(segment, offset)}; skipped")
                self.skipped += 1
        self._scanned = True

    def scan(self) -> RunLogReader:
        """Read the whole log once (CRC checks only) so that ended/torn/note are known; returns self."""
        if not self._scanned:
            self._reset()
            for _, _, payload in self._frames():
                if payload[:1] == KIND_END:
                    self._read_end(payload)
            self._scanned = True
        return self

    def status(self) -> dict[str, Any]:
        """What the reader found, as plain data (for summaries and reports)."""
        self.scan()
        return {"ended": self.ended, "torn": self.torn, "torn_segment": self.torn_segment,
                "torn_offset": self.torn_offset, "skipped_records": self.skipped,
                "undecoded_messages": self.undecoded, "note": self.note}

    def _reset(self) -> None:
        self.ended, self.summary, self.torn = False, None, False
        self.torn_segment = self.torn_offset = None
        self.note, self.skipped, self.undecoded = "", 0, 0

    def _decode(self, segment: int, offset: int, payload: memoryview) -> LogRecord | None:
        if len(payload) < 1 + RECEIVE_TIME.size:  # a checksum only says the bytes are as written
            self.skipped += 1
            self._note(f"a message record of {len(payload)} bytes at {self._where(segment, offset)} is too short "
                       f"(a receive time alone takes {1 + RECEIVE_TIME.size}); skipped")
            return None
        body = bytes(payload[1 + RECEIVE_TIME.size:])
        (t_received,) = RECEIVE_TIME.unpack_from(payload, 1)
        try:
            return LogRecord(t_received, decode(body), segment, offset)
        except ProtocolError as exc:
            name = _type_name(body)
            if name is not None and name not in MESSAGE_TYPES:
                self.undecoded += 1
                return LogRecord(t_received, UndecodedMessage(name, body), segment, offset)
            self.skipped += 1
            self._note(f"message at {self._where(segment, offset)} does not decode ({exc}); skipped")
            return None

    def _read_end(self, payload: memoryview) -> None:
        self.ended = True
        try:
            summary = msgpack.unpackb(payload[1:], raw=False)
        except (ValueError, msgpack.UnpackException):
            summary = None
        self.summary = summary if isinstance(summary, dict) else {}

    def _frames(self) -> Iterator[tuple[int, int, memoryview]]:
        """(segment, offset, payload) of every frame that checks out, in order; sets torn/note on damage."""
        last = len(self.segments) - 1
        for index, path in enumerate(self.segments):
            try:
                data = memoryview(path.read_bytes())
            except OSError as exc:
                raise DataFormatError(f"cannot read run log segment {path}: {exc.strerror}") from exc
            pos = 0
            while pos < len(data):
                problem, end = _check_frame(data, pos)
                if problem is None:
                    yield index, pos, data[pos + FRAME_HEADER.size:end]
                    pos = end
                    continue
                next_ok = end < len(data) and _check_frame(data, end)[0] is None
                if end and (next_ok or (end == len(data) and index < last)):
                    self.skipped += 1
                    self._note(f"{problem} at {self._where(index, pos)}; skipped (the next record checks out)")
                    pos = end
                    continue
                self.torn, self.torn_segment, self.torn_offset = True, index, pos
                later = sum(p.stat().st_size for p in self.segments[index + 1:])
                where = "the tail of the log is torn (a write cut short)" if index == last else "the log is corrupt"
                self._note(f"{where}: {problem} at {self._where(index, pos)}; reading stopped there, "
                           f"{len(data) - pos + later} bytes not read")
                return

    def _where(self, segment: int, offset: int) -> str:
        return f"{self.segments[segment].name} byte {offset}"

    def _note(self, text: str) -> None:
        self.note = f"{self.note}; {text}" if self.note else text


def _check_frame(data: memoryview, pos: int) -> tuple[str | None, int]:
    """(None, end) for a good frame at pos; else (what is wrong, end if the length field is usable else 0)."""
    if len(data) - pos < FRAME_HEADER.size:
        return f"an incomplete frame header ({len(data) - pos} of {FRAME_HEADER.size} bytes)", 0
    magic, length, crc = FRAME_HEADER.unpack_from(data, pos)
    if magic != MAGIC:
        return "no record marker", 0
    end = pos + FRAME_HEADER.size + length
    if length > MAX_RECORD_BYTES or end > len(data):
        return f"a record of {length} bytes that runs past the end of the file", 0
    if frame_crc(data[pos + FRAME_HEADER.size:end]) != crc or length == 0:
        return "a record whose CRC does not match", end
    return None, end


def _type_name(body: bytes) -> str | None:
    try:
        name = msgpack.unpackb(body, raw=False)[0]
    except (ValueError, TypeError, IndexError, KeyError, msgpack.UnpackException):
        return None
    return name if isinstance(name, str) else None


def _segment_paths(run_dir: Path) -> list[Path]:
    """The run's segments in order; a gap in the numbering is an error that names the missing file."""
    found = sorted(run_dir.glob("log-[0-9][0-9][0-9].msgpack"))
    if not found:
        raise DataFormatError(f"no run log (log-000.msgpack) in {run_dir}; is this a run directory?")
    for index, path in enumerate(found):
        if path != segment_path(run_dir, index):
            raise DataFormatError(f"run log segment {segment_path(run_dir, index).name} is missing in {run_dir}")
    return found
