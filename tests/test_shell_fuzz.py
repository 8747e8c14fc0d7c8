"""Fuzz the shell: random and malformed lines never crash it and every line gets exactly one reply."""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
import tty
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from gprbot.shell.commands import CommandError, parse_command
from gprbot.shell.fake import FakeHandler
from gprbot.shell.handler import EventBus
from gprbot.shell.protocol import LineSplitter, Reply, ReplyReader, ServerReply, encode_reply
from gprbot.shell.server import SerialShell, ShellServer
from tests.aio import within

VERBS = ["help", "status", "jog", "stop", "estop", "reset", "survey", "runs", "files", "pull", "auth", "fly", ""]
ARGS = ["0.1", "-2", "1e309", "nan", "start", "pause", "lines=3", "spacing=0.1", "speed=x", "..", "/etc/passwd",
        "run1", "'quoted arg'", "'unclosed", "a/../b", "ü", "\t", "=", "lines=", "--", "\\"]


def random_line(rng: random.Random, max_line: int) -> bytes:
    """A line without its newline: plausible commands, random bytes, over-long and invalid UTF-8."""
    kind = rng.random()
    if kind < 0.45:
        words = [rng.choice(VERBS)] + [rng.choice(ARGS) for _ in range(rng.randint(0, 5))]
        return " ".join(words).encode()
    if kind < 0.75:
        return bytes(rng.choice(range(256)) for _ in range(rng.randint(0, 40))).replace(b"\n", b"")
    if kind < 0.85:
        return b"status " + b"x" * rng.randint(max_line - 8, 3 * max_line)
    if kind < 0.95:
        return rng.choice([b"\xff\xfe", b"\xc3", b"st\xe2\x82atus", b"\x00", b"jog 1 2 3\r\r"])
    return b""


def random_stream(seed: int, count: int, max_line: int) -> bytes:
    """`count` random lines joined with LF or CRLF."""
    rng = random.Random(seed)
    return b"".join(random_line(rng, max_line) + rng.choice([b"\n", b"\r\n"]) for _ in range(count))


def count_replies(data: bytes) -> tuple[int, int]:
    """(ok/error lines, event lines) in the server's output, counted without the ReplyReader."""
    lines = data.split(b"\n")
    replies = sum(1 for line in lines if line == b"ok" or line.startswith((b"ok ", b"error ")))
    return replies, sum(1 for line in lines if line.startswith(b"* "))


async def test_thousands_of_random_lines_over_tcp_each_get_one_reply(tmp_path: Path) -> None:
    bus = EventBus()
    server = ShellServer(FakeHandler(tmp_path, bus), port=0, rate_per_s=1e9, events=bus)
    await server.start()
    rng = random.Random(7)
    try:
        for seed in range(5):
            stream = random_stream(seed, 2000, 256)
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            position = 0
            while position < len(stream):  # random chunking: lines split across writes
                step = rng.randint(1, 4096)
                writer.write(stream[position:position + step])
                position += step
            writer.write_eof()
            output = await within(reader.read(), 20)  # the server answers everything, then closes
            replies, _ = count_replies(output)
            assert replies == stream.count(b"\n") == 2000
            writer.close()
            await writer.wait_closed()
        assert server.client_count == 0
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        writer.write(b"status\n")
        assert (await within(reader.readuntil(b"ok status\n"), 5)).endswith(b"ok status\n")
        writer.close()
        await writer.wait_closed()
    finally:
        await server.close()


async def test_random_lines_over_serial_each_get_one_reply(tmp_path: Path) -> None:
    bus = EventBus()
    master, slave = os.openpty()
    tty.setraw(master)
    shell = SerialShell(FakeHandler(tmp_path, bus), os.ttyname(slave), events=bus, rate_per_s=1e9)
    await shell.start()
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    read_transport, _ = await loop.connect_read_pipe(
        lambda: asyncio.StreamReaderProtocol(reader), os.fdopen(os.dup(master), "rb", buffering=0)
    )
    write_transport, write_protocol = await loop.connect_write_pipe(
        lambda: asyncio.StreamReaderProtocol(asyncio.StreamReader()), os.fdopen(os.dup(master), "wb", buffering=0)
    )
    writer = asyncio.StreamWriter(write_transport, write_protocol, None, loop)
    try:
        stream = random_stream(11, 2000, 256)
        writer.write(stream)
        output = b""
        while count_replies(output)[0] < 2000:
            output += await within(reader.read(65536), 10)
        writer.write(b"status\n")  # anything beyond one reply per line would show up before this one's
        output += await within(reader.readuntil(b"ok status\n"), 10)
        assert count_replies(output)[0] == stream.count(b"\n") + 1 == 2001
    finally:
        write_transport.close()
        read_transport.close()
        await shell.close()
        os.close(master)
        os.close(slave)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=80), max_size=20), st.integers(min_value=1, max_value=64))
def test_splitter_yields_one_item_per_newline_and_parsing_only_raises_command_error(
    chunks: list[bytes], max_line: int
) -> None:
    splitter = LineSplitter(max_line)
    items = [item for chunk in chunks for item in splitter.feed(chunk)]
    assert len(items) == sum(chunk.count(b"\n") for chunk in chunks)
    for item in items:
        text = getattr(item, "text", "")
        with contextlib.suppress(CommandError):  # anything else escaping would fail the test
            parse_command(text)


@settings(max_examples=200, deadline=None)
@given(st.booleans(), st.text(max_size=60), st.lists(st.text(max_size=30), max_size=5))
def test_any_reply_survives_the_round_trip_through_the_client_reader(ok: bool, text: str, body: list[str]) -> None:
    from gprbot.shell.commands import ErrorCode

    reply = Reply.success(text, body) if ok else Reply.failure(ErrorCode.BAD_ARGUMENT, text)
    items = ReplyReader().feed(encode_reply(reply))
    assert len(items) == 1 and isinstance(items[0], ServerReply) and items[0].ok is ok
    sent = [s.replace("\r", " ").replace("\n", " ").encode("utf-8", "replace").decode() for s in body]
    assert list(items[0].body) == (sent if ok else [])
