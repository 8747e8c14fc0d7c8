"""The shell servers over real TCP sockets and a pty, with the fake robot; the client's pull end to end."""

from __future__ import annotations

import asyncio
import hashlib
import os
import socket
import struct
import subprocess
import sys
import threading
import tty
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest

from gprbot.drivers.motors.pty_link import PtyLink
from gprbot.errors import ConfigError, ProtocolError
from gprbot.shell.auth import create_token_file
from gprbot.shell.client import ShellCommandError, pull_run
from gprbot.shell.commands import Jog
from gprbot.shell.fake import FakeHandler
from gprbot.shell.handler import EventBus
from gprbot.shell.interactive import pull_main
from gprbot.shell.protocol import Reply
from gprbot.shell.server import SerialShell, ShellServer
from tests.aio import within

TIMEOUT = 5.0


class RawClient:
    """A deliberately simple client: reads lines with readline(), independent of the ReplyReader."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer
        self.events: list[str] = []

    @classmethod
    async def connect(cls, port: int) -> RawClient:
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        return cls(reader, writer)

    async def send(self, line: str | bytes) -> None:
        self.writer.write(line if isinstance(line, bytes) else line.encode() + b"\n")
        await self.writer.drain()

    async def line(self) -> str:
        data = await within(self.reader.readline(), TIMEOUT)
        assert data.endswith(b"\n"), f"connection closed, got {data!r}"
        return data[:-1].decode()

    async def reply(self) -> tuple[list[str], str]:
        """Body lines and the ok/error line of the next reply; events on the way go to .events."""
        body = []
        while True:
            text = await self.line()
            if text.startswith("* "):
                self.events.append(text[2:])
            elif text.startswith("= "):
                body.append(text[2:])
            else:
                assert text == "ok" or text.startswith(("ok ", "error ")), text
                return body, text

    async def ask(self, line: str) -> str:
        return (await self.ask_full(line))[1]

    async def ask_full(self, line: str) -> tuple[list[str], str]:
        await self.send(line)
        return await self.reply()

    async def close(self) -> None:
        self.writer.close()
        await self.writer.wait_closed()


@pytest.fixture
def runs_dir(tmp_path: Path) -> Path:
    runs = tmp_path / "runs"
    (runs / "run1" / "png").mkdir(parents=True)
    (runs / "run1" / "cloud.ply").write_bytes(os.urandom(300_000))
    (runs / "run1" / "pipes.json").write_text('{"pipes": []}\n')
    (runs / "run1" / "png" / "line 1.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    (runs / "run1" / "empty.txt").write_bytes(b"")
    (tmp_path / "secret.txt").write_text("operator password\n")
    (runs / "run1" / "escape.txt").symlink_to(tmp_path / "secret.txt")
    (runs / "evil").symlink_to(tmp_path)
    return runs


@pytest.fixture
async def server(runs_dir: Path) -> AsyncIterator[ShellServer]:
    bus = EventBus()
    shell = ShellServer(FakeHandler(runs_dir, bus), port=0, events=bus, max_clients=3)
    await shell.start()
    yield shell
    await shell.close()


def fake(server: ShellServer) -> FakeHandler:
    handler = server._handler
    assert isinstance(handler, FakeHandler)
    return handler


async def test_replies_and_session_survives_errors(server: ShellServer) -> None:
    client = await RawClient.connect(server.port)
    assert await client.ask("jog 0.2 0 1.5") == "ok jog 0.2 0 1.5"
    assert (await client.ask("fly away")).startswith("error bad_command ")
    assert (await client.ask("jog x 0 1")).startswith("error bad_argument VX")
    await client.send(b"x" * 300 + b"\r\n")
    assert (await client.reply())[1].startswith("error too_long ")
    await client.send(b"\xff\xfe\n")
    assert (await client.reply())[1].startswith("error bad_command ")
    body, status = await client.ask_full("status")
    assert status == "ok status" and body == ["mode idle", "commands 2"]
    body, status = await client.ask_full("help")
    assert status == "ok help" and len(body) == 11
    assert await client.ask("") == "ok"
    assert fake(server).handled[0] == (Jog(0.2, 0.0, 1.5), 1)
    await client.close()


async def test_events_reach_every_client(server: ShellServer) -> None:
    clients = [await RawClient.connect(server.port) for _ in range(3)]
    for client in clients:
        assert await client.ask("status") == "ok status"  # connected and subscribed
    server.broadcast("survey line 3 done")
    for client in clients:
        assert await client.line() == "* survey line 3 done"
        await client.close()


async def test_estop_overtakes_a_queued_command(server: ShellServer) -> None:
    handler = fake(server)
    handler.gate = asyncio.Event()
    other = await RawClient.connect(server.port)
    assert await other.ask("help") == "ok help"
    client = await RawClient.connect(server.port)
    await client.send(b"jog 0.3 0 5\nstatus\nestop\n")
    # the handler's `* estop` event, then the reply, while the jog is still held at the gate
    assert [await client.line(), await client.line()] == ["* estop", "ok estop"]
    assert handler.estops == [2] and handler.handled == []
    assert await other.line() == "* estop"
    handler.gate.set()
    _, jog_reply = await client.reply()
    assert jog_reply.startswith("error estopped ")
    assert (await client.reply())[1] == "ok status"
    await client.close()
    await other.close()


async def test_token_server_refuses_unauthenticated_commands_but_not_estop(runs_dir: Path, tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token = create_token_file(token_file)
    bus = EventBus()
    handler = FakeHandler(runs_dir, bus)
    shell = ShellServer(handler, host="0.0.0.0", port=0, token_file=token_file, events=bus)
    await shell.start()
    try:
        client = await RawClient.connect(shell.port)
        assert (await client.ask("status")).startswith("error unauthorized ")
        assert (await client.ask("runs")).startswith("error unauthorized ")
        assert (await client.ask("help")) == "ok help"
        assert await client.ask("estop") == "ok estop"
        assert handler.estops == [1] and handler.handled == []
        assert (await client.ask("auth " + "x" * len(token))).startswith("error unauthorized wrong token")
        assert await client.ask(f"auth {token}") == "ok auth"
        assert await client.ask("status") == "ok status"
        await client.close()
    finally:
        await shell.close()


async def test_non_loopback_without_token_or_with_a_readable_token_file_refuses_to_start(
    runs_dir: Path, tmp_path: Path
) -> None:
    with pytest.raises(ConfigError, match="without a token"):
        await ShellServer(FakeHandler(runs_dir), host="0.0.0.0", port=0).start()
    loose = tmp_path / "loose-token"
    loose.write_text("a" * 32 + "\n")
    loose.chmod(0o640)
    with pytest.raises(ConfigError, match="chmod 600"):
        await ShellServer(FakeHandler(runs_dir), host="0.0.0.0", port=0, token_file=loose).start()
    with pytest.raises(ConfigError, match="does not exist"):
        await ShellServer(FakeHandler(runs_dir), host="0.0.0.0", port=0, token_file=tmp_path / "none").start()


async def test_pull_sends_exact_bytes_and_sha256_then_the_session_goes_on(server: ShellServer, runs_dir: Path) -> None:
    client = await RawClient.connect(server.port)
    expected = (runs_dir / "run1" / "cloud.ply").read_bytes()
    await client.send("pull run1 cloud.ply")
    verb, size, sha = (await client.line()).split()[1:]
    assert verb == "pull" and int(size) == len(expected) and sha == hashlib.sha256(expected).hexdigest()
    data = await within(client.reader.readexactly(int(size)), TIMEOUT)
    assert data == expected
    assert await client.ask("status") == "ok status"
    body, status = await client.ask_full("files run1")
    assert status == "ok files 4"
    assert body == [f"{len(expected)} cloud.ply", "0 empty.txt", "14 pipes.json", "264 png/line 1.png"]
    await client.close()


@pytest.mark.parametrize(
    ("line", "code"),
    [
        ("pull run1 escape.txt", "bad_argument"),  # a symlink out of the runs directory
        ("pull run1 ../secret.txt", "bad_argument"),
        ("pull evil secret.txt", "bad_argument"),  # a run directory that is a symlink out
        ("pull run1 missing.ply", "not_found"),
        ("pull run1 png", "not_found"),
        ("files evil", "not_found"),
        ("files nope", "not_found"),
    ],
)
async def test_pull_cannot_leave_the_runs_directory(server: ShellServer, line: str, code: str) -> None:
    client = await RawClient.connect(server.port)
    assert (await client.ask(line)).startswith(f"error {code} ")
    await client.close()


async def test_client_limit_refuses_the_extra_connection(server: ShellServer) -> None:
    clients = [await RawClient.connect(server.port) for _ in range(3)]
    for client in clients:
        assert await client.ask("status") == "ok status"
    extra = await RawClient.connect(server.port)
    assert await extra.ask("estop") == "ok estop"  # e-stop gets through a full server
    assert (await extra.ask("status")).startswith("error busy too many clients")
    assert await within(extra.reader.read(), TIMEOUT) == b""
    await clients[0].close()
    for _ in range(100):  # the server notices the close asynchronously
        if server.client_count < 3:
            break
        await asyncio.sleep(0.01)
    again = await RawClient.connect(server.port)
    assert await again.ask("status") == "ok status"
    for client in (*clients[1:], extra, again):
        await client.close()


async def test_rate_limit_uses_the_injected_clock_and_spares_estop(runs_dir: Path) -> None:
    now = [100.0]
    shell = ShellServer(FakeHandler(runs_dir), port=0, rate_per_s=5, clock=lambda: now[0])
    await shell.start()
    try:
        client = await RawClient.connect(shell.port)
        await client.send(b"status\n" * 8 + b"estop\n")
        replies = [(await client.reply())[1] for _ in range(9)]
        assert replies.count("ok estop") == 1
        statuses = [r for r in replies if r != "ok estop"]
        assert statuses[:5] == ["ok status"] * 5
        assert all(r.startswith("error rate_limited ") for r in statuses[5:])
        now[0] += 0.4  # 0.4 s × 5/s = 2 new tokens
        await client.send(b"status\n" * 3)
        assert [(await client.reply())[1][:9] for _ in range(3)] == ["ok status", "ok status", "error rat"]
        await client.close()
    finally:
        await shell.close()


async def test_serial_shell_over_a_pty(runs_dir: Path) -> None:
    bus = EventBus()
    handler = FakeHandler(runs_dir, bus)
    master, slave = os.openpty()
    tty.setraw(master)
    serial_shell = SerialShell(handler, os.ttyname(slave), events=bus)
    await serial_shell.start()
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    read_transport, _ = await loop.connect_read_pipe(
        lambda: asyncio.StreamReaderProtocol(reader), os.fdopen(os.dup(master), "rb", buffering=0)
    )
    try:
        async def exchange(data: bytes, count: int) -> list[bytes]:
            os.write(master, data)
            return [await within(reader.readline(), TIMEOUT) for _ in range(count)]

        assert await exchange(b"status\r\n", 3) == [b"= mode idle\n", b"= commands 1\n", b"ok status\n"]
        assert await exchange(b"jog 0.1 0.1 1\n", 1) == [b"ok jog 0.1 0.1 1\n"]
        assert await exchange(b"estop\n", 2) == [b"* estop\n", b"ok estop\n"]
        assert (await exchange(b"jog 0.1 0 1\n", 1))[0].startswith(b"error estopped ")
        assert await exchange(b"reset\njog 0.1 0 1\n", 2) == [b"ok reset\n", b"ok jog 0.1 0 1\n"]
        assert await exchange(b"x" * 400 + b"\n", 1) == [b"error too_long line longer than 256 bytes; ignored\n"]
        bus.broadcast("survey line 1 done")
        assert await within(reader.readline(), TIMEOUT) == b"* survey line 1 done\n"
        assert handler.estops == [-1]
    finally:
        read_transport.close()
        await serial_shell.close()
        os.close(master)
        os.close(slave)


async def test_pull_run_end_to_end_with_token(runs_dir: Path, tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token = create_token_file(token_file)
    shell = ShellServer(FakeHandler(runs_dir), port=0, token_file=token_file)
    await shell.start()
    try:
        dest = tmp_path / "laptop" / "run1"
        written = await pull_run("127.0.0.1", shell.port, "run1", dest, token)
        names = sorted(p.relative_to(dest).as_posix() for p in written)
        assert names == ["cloud.ply", "empty.txt", "pipes.json", "png/line 1.png"]
        for name in names:
            assert (dest / name).read_bytes() == (runs_dir / "run1" / name).read_bytes()
        assert not list(dest.rglob("*.part"))
        with pytest.raises(ShellCommandError, match="unauthorized"):
            await pull_run("127.0.0.1", shell.port, "run1", dest, "wrong-token-wrong-token")
    finally:
        await shell.close()


async def test_pull_run_rejects_a_corrupted_file_and_leaves_nothing(tmp_path: Path) -> None:
    async def lying_server(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        assert await reader.readline() == b"files run1\n"
        writer.write(b"= 5 data.bin\nok files 1\n")
        assert await reader.readline() == b"pull run1 data.bin\n"
        writer.write(f"ok pull 5 {hashlib.sha256(b'hello').hexdigest()}\n".encode() + b"hellO")
        await writer.drain()
        await reader.read()
        writer.close()

    fake_server = await asyncio.start_server(lying_server, "127.0.0.1", 0)
    port = fake_server.sockets[0].getsockname()[1]
    try:
        with pytest.raises(ProtocolError, match="sha256 mismatch"):
            await pull_run("127.0.0.1", port, "run1", tmp_path / "out")
        assert list((tmp_path / "out").iterdir()) == []
    finally:
        fake_server.close()
        await fake_server.wait_closed()


async def test_commands_queued_by_a_client_whose_connection_reset_do_not_run(server: ShellServer) -> None:
    handler = fake(server)
    handler.gate = asyncio.Event()
    client = await RawClient.connect(server.port)
    assert await client.ask("help") == "ok help"
    await client.send(b"status\njog 0.3 0 5\njog 0.3 0 5\n")
    await asyncio.sleep(0.05)  # let the server read them (the status call is held at the gate)
    sock = client.writer.get_extra_info("socket")
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # close → RST
    client.writer.transport.abort()
    (session,) = server._sessions.values()
    for _ in range(200):  # until the server has seen the reset (its status call still held at the gate)
        if session._writer.is_closing():
            break
        await asyncio.sleep(0.01)
    handler.gate.set()
    for _ in range(200):
        if server.client_count == 0:
            break
        await asyncio.sleep(0.01)
    assert server.client_count == 0
    assert [type(command).__name__ for command, _ in handler.handled] == ["Status"]


class FailingHandler(FakeHandler):
    async def handle(self, command: object, session: object) -> Reply:  # type: ignore[override]
        raise ValueError("wheel 2 encoder unplugged")


async def test_a_failing_handler_costs_one_error_reply_not_the_session(runs_dir: Path) -> None:
    shell = ShellServer(FailingHandler(runs_dir), port=0)
    await shell.start()
    try:
        client = await RawClient.connect(shell.port)
        assert await client.ask("stop") == "error internal ValueError: wheel 2 encoder unplugged"
        assert await client.ask("runs") == "ok runs 1"  # `evil` is a symlink, not a run
        assert await client.ask("estop") == "ok estop"
        await client.close()
    finally:
        await shell.close()


async def test_repeated_wrong_tokens_end_the_session(runs_dir: Path, tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    create_token_file(token_file)
    shell = ShellServer(FakeHandler(runs_dir), port=0, token_file=token_file)
    await shell.start()
    try:
        client = await RawClient.connect(shell.port)
        await client.send(b"auth guess-guess-guess-1\n" * 5 + b"status\n")
        for _ in range(5):
            assert (await client.reply())[1] == "error unauthorized wrong token"
        assert await within(client.reader.read(), TIMEOUT) == b""  # closed: no reply to status
        await client.close()
    finally:
        await shell.close()


@pytest.fixture
def threaded_server(runs_dir: Path) -> Iterator[ShellServer]:
    """A server on its own loop in a thread, for the synchronous command-line entry points."""
    loop = asyncio.new_event_loop()
    shell = ShellServer(FakeHandler(runs_dir), port=0)
    loop.run_until_complete(shell.start())
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    yield shell
    asyncio.run_coroutine_threadsafe(shell.close(), loop).result(TIMEOUT)
    loop.call_soon_threadsafe(loop.stop)
    thread.join(TIMEOUT)
    loop.close()


def test_pull_main_command_line_end_to_end(
    threaded_server: ShellServer, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dest = tmp_path / "pulled"
    assert pull_main([f"127.0.0.1:{threaded_server.port}", "run1", str(dest)]) == 0
    assert (dest / "pipes.json").read_text() == '{"pipes": []}\n'
    assert str(dest / "cloud.ply") in capsys.readouterr().out
    assert pull_main([f"127.0.0.1:{threaded_server.port}", "nope", str(dest)]) == 1
    assert "not_found" in capsys.readouterr().err


def test_interactive_shell_in_a_subprocess(threaded_server: ShellServer, tmp_path: Path) -> None:
    script = "import sys; from gprbot.shell.interactive import shell_main; sys.exit(shell_main(sys.argv[1:]))"
    done = subprocess.run(
        [sys.executable, "-c", script, f"127.0.0.1:{threaded_server.port}"],
        input="status\nfly\npull run1 pipes.json\nquit\n", capture_output=True, text=True, timeout=30,
        cwd=tmp_path, env={**os.environ, "HOME": str(tmp_path)},
    )
    assert done.returncode == 0, done.stderr
    assert "  mode idle\n" in done.stdout and "ok status\n" in done.stdout
    assert "error bad_command unknown command 'fly'" in done.stdout
    assert (tmp_path / "pipes.json").read_text() == '{"pipes": []}\n'
    failed = subprocess.run(  # like sh: the exit status is the last command's
        [sys.executable, "-c", script, f"127.0.0.1:{threaded_server.port}"], input="status\nfly\n",
        capture_output=True, text=True, timeout=30, cwd=tmp_path, env={**os.environ, "HOME": str(tmp_path)},
    )
    assert failed.returncode == 1, failed.stderr


def test_shell_dash_c_exits_with_the_replys_status(threaded_server: ShellServer,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    from gprbot.cli import main

    address = f"127.0.0.1:{threaded_server.port}"
    assert main(["shell", address, "-c", "status"]) == 0
    assert "ok status" in capsys.readouterr().out
    assert main(["shell", address, "-c", "status", "-c", "fly", "-c", "status"]) == 1
    out = capsys.readouterr().out
    assert "error bad_command unknown command 'fly'" in out and out.count("ok status") == 1  # stops at the error
    assert main(["shell", address, "-c", "estop"]) == 0
    assert main(["shell", address, "-c", "jog 0.1 0 1"]) == 1
    assert "estopped" in capsys.readouterr().out


async def test_close_does_not_wait_for_a_stuck_handler(runs_dir: Path) -> None:
    handler = FakeHandler(runs_dir)
    handler.gate = asyncio.Event()  # never opened: the robot side hangs
    shell = ShellServer(handler, port=0)
    await shell.start()
    client = await RawClient.connect(shell.port)
    await client.send("status")
    await asyncio.sleep(0.05)
    await within(shell.close(grace_s=0.1), TIMEOUT)
    assert shell.client_count == 0
    assert await within(client.reader.read(), TIMEOUT) == b""
    await client.close()


async def test_serial_shell_reopens_the_port_after_a_hang_up(runs_dir: Path, tmp_path: Path) -> None:
    received = bytearray()

    def collect(data: bytes) -> bytes:
        received.extend(data)
        return b""

    link = PtyLink(collect, tmp_path / "console")  # a stable path re-pointed on "replug", like udev's
    serial_shell = SerialShell(FakeHandler(runs_dir), link.open(), reopen_s=0.05)
    await serial_shell.start()

    async def answered(line: bytes, reply: bytes) -> bool:
        received.clear()
        for _ in range(100):
            link.write(line)
            for _ in range(5):
                await asyncio.sleep(0.01)
                if reply in received:
                    return True
        return False

    try:
        assert await answered(b"status\n", b"ok status\n")
        link.close()  # cable pulled
        await asyncio.sleep(0.1)
        link.open()  # plugged back: a new pty behind the same path
        assert await answered(b"status\n", b"ok status\n")
        assert serial_shell._sessions_started == 2
    finally:
        await serial_shell.close()
        link.close()
