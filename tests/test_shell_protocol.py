"""The shell's sans-IO line protocol and command grammar: bytes in, bytes out."""

from __future__ import annotations

import hashlib

import pytest

from gprbot.errors import ProtocolError
from gprbot.shell.commands import (
    Auth,
    CommandError,
    Empty,
    ErrorCode,
    Estop,
    Files,
    Help,
    Jog,
    Pull,
    Reset,
    Runs,
    Status,
    Stop,
    SurveyControl,
    SurveyStart,
    help_lines,
    parse_command,
)
from gprbot.shell.protocol import (
    LineReceived,
    LineRejected,
    LineSplitter,
    PayloadChunk,
    Reply,
    ReplyReader,
    ServerEvent,
    ServerReply,
    encode_event,
    encode_reply,
)

# --- LineSplitter: bytes → lines ---------------------------------------------------------------


def test_lines_split_on_lf_and_crlf() -> None:
    splitter = LineSplitter()
    assert splitter.feed(b"status\nstop\r\nhelp jog\n") == [
        LineReceived("status"), LineReceived("stop"), LineReceived("help jog")
    ]


def test_partial_lines_are_joined_across_feeds_byte_by_byte() -> None:
    splitter = LineSplitter()
    out = []
    for byte in b"jog 0.1 0 2\r\nest":
        out += splitter.feed(bytes([byte]))
    assert out == [LineReceived("jog 0.1 0 2")]
    assert splitter.feed(b"op\n") == [LineReceived("estop")]


def test_incomplete_line_yields_nothing() -> None:
    assert LineSplitter().feed(b"status") == []


def test_line_of_exactly_max_bytes_is_accepted_one_more_is_too_long() -> None:
    splitter = LineSplitter(max_line=8)
    assert splitter.feed(b"a" * 8 + b"\r\n") == [LineReceived("a" * 8)]
    out = splitter.feed(b"b" * 9 + b"\n")
    assert len(out) == 1 and isinstance(out[0], LineRejected) and out[0].code is ErrorCode.TOO_LONG


def test_over_long_line_gets_one_rejection_at_its_end_and_the_next_line_still_works() -> None:
    splitter = LineSplitter(max_line=16)
    out = splitter.feed(b"x" * 10)
    out += splitter.feed(b"y" * 5000)  # skipped, not buffered
    assert out == [] and len(splitter._buffer) == 0
    out = splitter.feed(b"zzz\nstatus\n")
    assert len(out) == 2 and isinstance(out[0], LineRejected) and out[0].code is ErrorCode.TOO_LONG
    assert out[1] == LineReceived("status")


def test_invalid_utf8_is_rejected_as_bad_command() -> None:
    out = LineSplitter().feed(b"st\xffatus\n\xc3\x28\nstatus\n")
    assert [getattr(item, "code", None) for item in out] == [ErrorCode.BAD_COMMAND, ErrorCode.BAD_COMMAND, None]
    assert out[2] == LineReceived("status")


def test_non_ascii_utf8_is_decoded() -> None:
    assert LineSplitter().feed("files läuf\n".encode()) == [LineReceived("files läuf")]


# --- encoding replies and events -----------------------------------------------------------------


def test_reply_and_event_bytes() -> None:
    assert encode_reply(Reply.success()) == b"ok\n"
    assert encode_reply(Reply.success("runs 2", ["b", "a"])) == b"= b\n= a\nok runs 2\n"
    assert encode_reply(Reply.failure(ErrorCode.BUSY, "survey running")) == b"error busy survey running\n"
    assert encode_event("survey line 3 done") == b"* survey line 3 done\n"


def test_newlines_inside_texts_cannot_forge_lines() -> None:
    data = encode_reply(Reply.failure(ErrorCode.INTERNAL, "a\nok fake\r\n"))
    assert data.count(b"\n") == 1 and data.startswith(b"error internal a ok fake")
    assert encode_event("x\n* y").count(b"\n") == 1


# --- ReplyReader: the client side ---------------------------------------------------------------


def test_reader_pairs_body_with_reply_and_passes_events() -> None:
    reader = ReplyReader()
    items = reader.feed(b"* estop\n= mode idle\n= pose 0 0\nok status\nerror bad_argument VX must be a number\n")
    assert items == [
        ServerEvent("estop"),
        ServerReply(True, None, "status", ("mode idle", "pose 0 0")),
        ServerReply(False, "bad_argument", "VX must be a number", ()),
    ]


def test_reader_switches_to_raw_bytes_after_pull_header_even_if_they_look_like_lines() -> None:
    payload = b"ok fake\n* not an event\n\x00\xff"
    sha = hashlib.sha256(payload).hexdigest()
    stream = f"ok pull {len(payload)} {sha}\n".encode() + payload + b"* after\n"
    reader = ReplyReader()
    items = []
    for i in range(0, len(stream), 7):
        items += reader.feed(stream[i:i + 7])
    header = items[0]
    assert isinstance(header, ServerReply) and header.payload_size == len(payload) and header.payload_sha256 == sha
    chunks = [item for item in items if isinstance(item, PayloadChunk)]
    assert b"".join(c.data for c in chunks) == payload and chunks[-1].last and not any(c.last for c in chunks[:-1])
    assert items[-1] == ServerEvent("after")


def test_reader_empty_pull_gives_one_last_chunk() -> None:
    sha = hashlib.sha256(b"").hexdigest()
    items = ReplyReader().feed(f"ok pull 0 {sha}\nok\n".encode())
    assert items[1] == PayloadChunk(b"", True) and items[2] == ServerReply(True, None, "", ())


def test_reader_rejects_garbage_and_endless_lines() -> None:
    with pytest.raises(ProtocolError):
        ReplyReader().feed(b"HTTP/1.1 400 Bad Request\n")
    with pytest.raises(ProtocolError):
        ReplyReader(max_line=100).feed(b"o" * 101)


# --- commands ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("line", "command"),
    [
        ("", Empty()),
        ("   ", Empty()),
        ("help", Help(None)),
        ("HELP Jog", Help("jog")),
        ("status", Status()),
        ("jog 0.2 -0.1 1.5", Jog(0.2, -0.1, 1.5)),
        ("jog 0 0 30", Jog(0.0, 0.0, 30.0)),
        ("stop", Stop()),
        ("estop", Estop()),
        ("  EStop  ", Estop()),
        ("reset", Reset()),
        ("survey start lines=10 spacing=0.1 length=2 speed=0.2", SurveyStart(10, 0.1, 2.0, 0.2)),
        ("survey start speed=0.3 lines=4", SurveyStart(4, None, None, 0.3)),
        ("survey start", SurveyStart()),
        ("survey pause", SurveyControl("pause")),
        ("survey resume", SurveyControl("resume")),
        ("survey abort", SurveyControl("abort")),
        ("runs", Runs()),
        ("files demo-20261123-1200", Files("demo-20261123-1200")),
        ("pull run1 cloud_dense.ply", Pull("run1", "cloud_dense.ply")),
        ("pull run1 'png/line 3.png'", Pull("run1", "png/line 3.png")),
        ("auth s3cr3t-token-value", Auth("s3cr3t-token-value")),
    ],
)
def test_each_command_parses(line: str, command: object) -> None:
    assert parse_command(line) == command


@pytest.mark.parametrize(
    ("line", "code"),
    [
        ("fly 1 2", ErrorCode.BAD_COMMAND),
        ("jog 1 2", ErrorCode.BAD_ARGUMENT),
        ("jog a 0 1", ErrorCode.BAD_ARGUMENT),
        ("jog nan 0 1", ErrorCode.BAD_ARGUMENT),
        ("jog inf 0 1", ErrorCode.BAD_ARGUMENT),
        ("jog 0.1 0 0", ErrorCode.BAD_ARGUMENT),
        ("jog 0.1 0 -1", ErrorCode.BAD_ARGUMENT),
        ("jog 0.1 0 31", ErrorCode.BAD_ARGUMENT),
        ("jog 9 0 1", ErrorCode.BAD_ARGUMENT),
        ("status now", ErrorCode.BAD_ARGUMENT),
        ("estop please", ErrorCode.BAD_ARGUMENT),
        ("survey", ErrorCode.BAD_ARGUMENT),
        ("survey fly", ErrorCode.BAD_ARGUMENT),
        ("survey start lines=0", ErrorCode.BAD_ARGUMENT),
        ("survey start lines=2.5", ErrorCode.BAD_ARGUMENT),
        ("survey start lines=-3", ErrorCode.BAD_ARGUMENT),
        ("survey start lines=3 lines=4", ErrorCode.BAD_ARGUMENT),
        ("survey start depth=3", ErrorCode.BAD_ARGUMENT),
        ("survey start spacing", ErrorCode.BAD_ARGUMENT),
        ("survey start spacing=0", ErrorCode.BAD_ARGUMENT),
        ("survey pause now", ErrorCode.BAD_ARGUMENT),
        ("files", ErrorCode.BAD_ARGUMENT),
        ("files ..", ErrorCode.BAD_ARGUMENT),
        ("files a/b", ErrorCode.BAD_ARGUMENT),
        ("pull run1", ErrorCode.BAD_ARGUMENT),
        ("pull run1 ../../etc/passwd", ErrorCode.BAD_ARGUMENT),
        ("pull run1 /etc/passwd", ErrorCode.BAD_ARGUMENT),
        ("pull run1 a//b", ErrorCode.BAD_ARGUMENT),
        ("pull run1 a/./b", ErrorCode.BAD_ARGUMENT),
        ("pull run1 'a\\b'", ErrorCode.BAD_ARGUMENT),
        ("pull .. x", ErrorCode.BAD_ARGUMENT),
        ("auth", ErrorCode.BAD_ARGUMENT),
        ("status 'unclosed", ErrorCode.BAD_COMMAND),
        ("sta\x00tus", ErrorCode.BAD_COMMAND),
        ("status\rstop", ErrorCode.BAD_COMMAND),
    ],
)
def test_bad_lines_raise_command_error_with_code(line: str, code: ErrorCode) -> None:
    with pytest.raises(CommandError) as info:
        parse_command(line)
    assert info.value.code is code


def test_help_covers_every_command_and_unknown_topic_is_not_found() -> None:
    text = "\n".join(help_lines(None))
    for verb in ("help", "status", "jog", "stop", "estop", "reset", "survey", "runs", "files", "pull", "auth"):
        assert f"\n{verb} " in "\n" + text
    with pytest.raises(CommandError) as info:
        help_lines("fly")
    assert info.value.code is ErrorCode.NOT_FOUND
