"""Fuzz targets for every byte/text parser on the daemon's boundaries; each accepts any input and fails
only with an AssertionError or an exception that is not the parser's documented error.

Used briefly by tests/test_parser_fuzz.py (hypothesis, in the suite) and at length by
benchmarks/fuzz_parsers.py."""

from __future__ import annotations

import contextlib
import tempfile
from collections.abc import Callable
from pathlib import Path

from gprbot.config import parse_config
from gprbot.drivers.gpr.sdk_http import MAX_BODY_BYTES, MAX_HEAD_BYTES, HttpResponseParser
from gprbot.drivers.gpr.trace_stream import TraceFrame, TraceStreamParser
from gprbot.drivers.motors import protocol as rc
from gprbot.drivers.motors.device_side import RequestFramer
from gprbot.drivers.motors.replies import ReplyParser
from gprbot.errors import ConfigError, DataFormatError, ProtocolError
from gprbot.messages import SurveyEvent
from gprbot.runlog import RunLogWriter
from gprbot.runlog_reader import RunLogReader
from gprbot.shell.commands import CommandError, parse_command
from gprbot.shell.protocol import LineReceived, LineSplitter, ReplyReader


def http_response(data: bytes) -> None:
    """The NIC's HTTP replies, fed in two pieces then closed: a response or ProtocolError, bounded."""
    parser = HttpResponseParser()
    try:
        half = len(data) // 2
        response = parser.feed(data[:half]) or parser.feed(data[half:]) or parser.close()
    except ProtocolError:
        return
    assert len(response.body) <= MAX_BODY_BYTES + MAX_HEAD_BYTES


def trace_stream(data: bytes) -> None:
    """The NIC's data socket: only plausible frames come out, sequence numbers increase."""
    parser = TraceStreamParser(16)
    events = parser.feed(data[: len(data) // 3]) + parser.feed(data[len(data) // 3:]) + parser.close()
    sequences = [e.sequence for e in events if isinstance(e, TraceFrame)]
    assert sequences == sorted(set(sequences))


def shell_lines(data: bytes) -> None:
    """The shell server's side: lines split within bounds, each parsed or refused with CommandError."""
    splitter = LineSplitter(64)
    for item in splitter.feed(data):
        if isinstance(item, LineReceived):
            assert len(item.text.encode()) <= 65
            with contextlib.suppress(CommandError):
                parse_command(item.text)


def shell_replies(data: bytes) -> None:
    """The shell client's side: what a (hostile) server sends parses or raises ProtocolError."""
    with contextlib.suppress(ProtocolError):
        ReplyReader(max_line=1024).feed(data)


def roboclaw_replies(data: bytes) -> None:
    """Replies to a read, as the driver parses them: a reply, None (more bytes needed) or ProtocolError."""
    for request in (rc.read_encoder(128, 1), rc.read_speed(128, 2), rc.drive_speeds(129, 0, 0)):
        with contextlib.suppress(ProtocolError):
            ReplyParser(request).feed(data)


def roboclaw_requests(data: bytes) -> None:
    """The emulator's side: any bytes frame into packets or are dropped."""
    RequestFramer().feed(data, 0.0)


def config_text(data: bytes) -> None:
    """A config file: a Config or ConfigError, never a traceback."""
    with contextlib.suppress(ConfigError):
        parse_config(data.decode("utf-8", "replace"), "fuzz.yaml")


def _sample_log() -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        writer = RunLogWriter(Path(tmp), {"run": "fuzz"})
        for i in range(3):
            writer.append(SurveyEvent(float(i), "line_start", i), float(i))
        writer.close({"state": "done"})
        return (Path(tmp) / "log-000.msgpack").read_bytes()


SAMPLE_LOG = _sample_log()


def run_log(data: bytes) -> None:
    """A run log segment: the sample log with `data` spliced in; records or DataFormatError only."""
    cut = (len(data) * 7919) % (len(SAMPLE_LOG) + 1)
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "log-000.msgpack").write_bytes(SAMPLE_LOG[:cut] + data + SAMPLE_LOG[cut + len(data) % 7:])
        try:
            reader = RunLogReader(Path(tmp))
        except DataFormatError:
            return
        list(reader)
        reader.status()


TARGETS: dict[str, Callable[[bytes], None]] = {
    "http_response": http_response, "trace_stream": trace_stream, "shell_lines": shell_lines,
    "shell_replies": shell_replies, "roboclaw_replies": roboclaw_replies, "roboclaw_requests": roboclaw_requests,
    "config_text": config_text, "run_log": run_log,
}
