"""Issue 15 #1, #3, #4, #8: the TCP shell under clients that do not play by the rules.

Each test reproduces a defect a review found on the unfixed server (idle clients locking out e-stop,
unbounded held-back replies, token guessing across connections, unquotable tokens, events leaking to
strangers, a client that does not read holding up shutdown)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
from pathlib import Path

import pytest

from gprbot.shell.client import ShellConnection
from gprbot.shell.fake import FakeHandler
from gprbot.shell.handler import EventBus
from gprbot.shell.server import ShellServer
from tests.test_shell_server import RawClient

TOKEN = "s3cr3t-token-for-tests-0123"


@pytest.fixture
def token_file(tmp_path: Path) -> Path:
    path = tmp_path / "token"
    path.write_text(TOKEN + "\n")
    path.chmod(0o600)
    return path


async def _served(handler: FakeHandler, **kwargs: object) -> ShellServer:
    server = ShellServer(handler, port=0, **kwargs)  # type: ignore[arg-type]
    await server.start()
    return server


async def _closed_by_server(client: RawClient, timeout_s: float = 5.0) -> bytes:
    """Everything the server still sends until it closes the connection."""
    data = b""
    async with asyncio.timeout(timeout_s):
        while chunk := await client.reader.read(65536):
            data += chunk
    return data


async def _quietly_close(client: RawClient) -> None:
    client.writer.close()
    with contextlib.suppress(ConnectionError):
        await client.writer.wait_closed()


async def test_eight_idle_strangers_do_not_lock_out_estop_or_the_operator(tmp_path: Path, token_file: Path) -> None:
    handler = FakeHandler(tmp_path)
    server = await _served(handler, token_file=token_file, max_clients=8)
    try:
        idle = [await RawClient.connect(server.port) for _ in range(8)]  # never authenticate
        await asyncio.sleep(0.05)
        ninth = await RawClient.connect(server.port)
        assert await ninth.ask("estop") == "ok estop"
        operator = await RawClient.connect(server.port)
        assert await operator.ask(f"auth {TOKEN}") == "ok auth"
        assert await operator.ask("status") == "ok status"
        for client in (*idle, ninth, operator):
            await client.close()
    finally:
        await server.close()


async def test_a_connection_that_does_not_authenticate_in_time_is_closed_even_if_it_trickles(
        tmp_path: Path, token_file: Path) -> None:
    server = await _served(FakeHandler(tmp_path), token_file=token_file, auth_timeout_s=0.4)
    try:
        silent = await RawClient.connect(server.port)
        trickler = await RawClient.connect(server.port)
        loop = asyncio.get_running_loop()
        began = loop.time()
        for _ in range(3):  # slowloris: a byte every 0.1 s, never a line
            trickler.writer.write(b"a")
            await asyncio.sleep(0.1)
        assert (await _closed_by_server(trickler)).endswith(b"* closing: not authenticated within 0.4 s\n")
        assert loop.time() - began < 1.5
        assert b"closing" in await _closed_by_server(silent)
        for client in (silent, trickler):
            await _quietly_close(client)
    finally:
        await server.close()


async def test_an_idle_authenticated_session_is_closed_after_the_idle_timeout(tmp_path: Path) -> None:
    server = await _served(FakeHandler(tmp_path), idle_timeout_s=0.3)
    try:
        client = await RawClient.connect(server.port)
        assert await client.ask("status") == "ok status"
        assert b"closing: idle for 0.3 s" in await _closed_by_server(client)
        await _quietly_close(client)
    finally:
        await server.close()


async def test_connections_beyond_every_quota_get_busy_at_once(tmp_path: Path) -> None:
    server = await _served(FakeHandler(tmp_path), max_unauthenticated=1, max_overflow=1, overflow_window_s=5.0)
    try:
        held = [await RawClient.connect(server.port) for _ in range(2)]  # one pending, one overflow
        await asyncio.sleep(0.05)
        late = await RawClient.connect(server.port)
        assert (await late.line()).startswith("error busy too many clients")
        for client in (*held, late):
            await client.close()
    finally:
        await server.close()


async def test_wrong_tokens_lock_the_host_out_across_connections(tmp_path: Path, token_file: Path) -> None:
    from gprbot.shell.auth import AuthGuard

    now = [100.0]
    guard = AuthGuard(max_failures=5, lockout_s=(30.0, 900.0), global_per_s=1e6)
    server = await _served(FakeHandler(tmp_path), token_file=token_file, guard=guard, clock=lambda: now[0])
    try:
        compared = 0
        for _ in range(10):  # guesses spread over connections, as a guessing script would
            client = await RawClient.connect(server.port)
            reply = await client.ask("auth wrong-guess-0123456789")
            compared += reply.endswith("wrong token")
            await client.close()
        assert compared == 5  # the first five; then no guess is even compared
        client = await RawClient.connect(server.port)
        assert "locked out" in await client.ask(f"auth {TOKEN}")  # even the right token, from that host
        await client.close()
        now[0] += 31.0
        client = await RawClient.connect(server.port)
        assert await client.ask(f"auth {TOKEN}") == "ok auth"
        await client.close()
    finally:
        await server.close()


def test_the_guard_caps_guesses_from_all_hosts_together() -> None:
    from gprbot.shell.auth import AuthGuard

    guard = AuthGuard(max_failures=5, global_per_s=5.0)
    compared = 0
    for i in range(1000):  # a thousand hosts, each guessing once, within one second
        host = f"10.0.{i // 256}.{i % 256}"
        if guard.refusal(host, 0.0 + i * 1e-3) is None:
            compared += 1
            guard.failed(host, i * 1e-3)
    assert compared <= 10


@pytest.mark.parametrize("token", ["quote'in-the-middle-123", 'double"quote-in-it-1234', "back\\slash-in-it-12345"])
async def test_tokens_with_quotes_or_backslashes_authenticate(tmp_path: Path, token: str) -> None:
    path = tmp_path / "token"
    path.write_text(token + "\n")
    path.chmod(0o600)
    server = await _served(FakeHandler(tmp_path), token_file=path)
    try:
        async with ShellConnection("127.0.0.1", server.port) as conn:
            await conn.authenticate(token)  # our client
            assert (await conn.request("status")).ok
        raw = await RawClient.connect(server.port)  # a person typing into nc
        assert await raw.ask(f"auth {token}") == "ok auth"
        await raw.close()
    finally:
        await server.close()


async def test_unauthenticated_clients_receive_no_events(tmp_path: Path, token_file: Path) -> None:
    bus = EventBus()
    server = await _served(FakeHandler(tmp_path, bus), token_file=token_file, events=bus)
    try:
        stranger = await RawClient.connect(server.port)
        operator = await RawClient.connect(server.port)
        assert await operator.ask(f"auth {TOKEN}") == "ok auth"
        assert await stranger.ask("help") == "ok help"
        server.broadcast("survey line 3 done at x=1.20 y=0.40")
        assert await operator.line() == "* survey line 3 done at x=1.20 y=0.40"
        assert await stranger.ask("") == "ok"
        assert stranger.events == []
        await stranger.close()
        await operator.close()
    finally:
        await server.close()


def _big_run(runs_dir: Path, size: int = 32 << 20) -> None:
    run = runs_dir / "run-big"
    run.mkdir(parents=True)
    with (run / "big.bin").open("wb") as out:
        out.truncate(size)


def _no_reading_socket(port: int) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.setblocking(False)
    return sock


async def test_estops_during_a_stalled_pull_do_not_grow_memory_without_bound(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    _big_run(runs)
    server = await _served(FakeHandler(runs))
    try:
        sock = _no_reading_socket(server.port)
        sock.sendall(b"pull run-big big.bin\n")
        await asyncio.sleep(0.3)  # the stream starts and stalls: the client reads nothing
        session = next(iter(server._sessions.values()))
        flood = b"estop\n" * 600
        for _ in range(40):  # 24 000 e-stops, each with a reply held back behind the payload
            with contextlib.suppress(BlockingIOError):
                sock.send(flood)
            await asyncio.sleep(0.01)
        held = sum(len(d) for d in session._deferred)
        assert held <= session._limits.max_deferred_bytes
        sock.close()
    finally:
        async with asyncio.timeout(10):
            await server.close()


async def test_closing_the_server_is_not_held_up_by_a_client_that_stopped_reading_a_pull(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    _big_run(runs)
    server = await _served(FakeHandler(runs))
    sock = _no_reading_socket(server.port)
    try:
        sock.sendall(b"pull run-big big.bin\n")
        await asyncio.sleep(0.5)
        loop = asyncio.get_running_loop()
        began = loop.time()
        async with asyncio.timeout(10):
            await server.close(grace_s=0.5)
        assert loop.time() - began < 3.0
        assert server.client_count == 0
    finally:
        sock.close()


async def test_an_estop_flood_logs_a_bounded_number_of_lines(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    handler = FakeHandler(tmp_path)
    server = await _served(handler)
    try:
        client = await RawClient.connect(server.port)
        with caplog.at_level(logging.INFO, logger="gprbot.shell"):
            await client.send(b"estop\n" * 500)
            for _ in range(500):
                assert (await client.reply())[1] == "ok estop"
        assert len(handler.estops) == 500  # every e-stop is executed ...
        estop_lines = [r for r in caplog.records if "estop from" in r.getMessage()]
        assert len(estop_lines) <= 5  # ... but logged only a few times
        await client.close()
    finally:
        await server.close()


def test_peers_outside_allow_from_are_refused_but_loopback_never(tmp_path: Path) -> None:
    server = ShellServer(FakeHandler(tmp_path), allow_from=("192.168.10.0/24",))
    assert server._peer_allowed(("192.168.10.42", 5000))
    assert server._peer_allowed(("127.0.0.1", 5000)) and server._peer_allowed(("::1", 5000, 0, 0))
    assert not server._peer_allowed(("192.168.11.1", 5000))
    assert not server._peer_allowed(("10.0.0.1", 5000))
    assert ShellServer(FakeHandler(tmp_path))._peer_allowed(("10.0.0.1", 5000))  # no list: any peer
