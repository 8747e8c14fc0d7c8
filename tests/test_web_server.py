"""The web console's server against the daemon on the simulated robot, over real HTTP and WebSockets:
session cookie, login with the shell's token, CSRF and origin checks, the shell's limits, e-stop, jog
dead-man on a closed socket; and the pure pieces of the live feed."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import logging
import socket
import time
from collections.abc import AsyncIterator
from pathlib import Path

import aiohttp
import numpy as np
import pytest

from gprbot.daemon import serve
from gprbot.errors import ConfigError
from gprbot.robot.runtime import RobotRuntime
from gprbot.sdnotify import SdNotifier
from gprbot.shell.auth import create_token_file
from gprbot.web.live import decimate_samples, quantise, section_picture, stack_traces
from gprbot.web.server import WebConsole
from gprbot.web.sessions import COOKIE_NAME, CSRF_HEADER
from tests.web_support import web_config


@contextlib.asynccontextmanager
async def daemon(tmp_path: Path, token_file: Path | None = None, web_port: int = 0,
                 wait_for_web: bool = True) -> AsyncIterator[RobotRuntime]:
    """The daemon (no worker process) with its shell and console on free loopback ports."""
    stop = asyncio.Event()
    started: list[RobotRuntime] = []
    cfg = web_config(tmp_path)
    cfg = dataclasses.replace(cfg, web=dataclasses.replace(cfg.web, port=web_port))
    task = asyncio.create_task(serve(cfg, shell_port=0, stop=stop, use_worker=False,
                                     token_file=str(token_file) if token_file else None,
                                     notifier=SdNotifier(environ={}), on_ready=started.append))  # type: ignore[arg-type]
    async with asyncio.timeout(30):
        while not started or (started[0].web is None if wait_for_web else started[0].shell is None):
            assert not task.done(), f"the daemon exited with {task.result()}"
            await asyncio.sleep(0.02)
    try:
        yield started[0]
    finally:
        stop.set()
        async with asyncio.timeout(30):
            assert await task == 0


def client() -> aiohttp.ClientSession:
    """An HTTP client that keeps cookies from 127.0.0.1 (aiohttp refuses IP-address cookies by default)."""
    return aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True))


def base(rt: RobotRuntime) -> str:
    assert rt.web is not None
    return f"http://127.0.0.1:{rt.web.port}"


async def open_console(http: aiohttp.ClientSession, rt: RobotRuntime) -> str:
    """GET / (loopback, no token): the session cookie is set; the page's CSRF token."""
    async with http.get(base(rt) + "/") as page:
        assert page.status == 200
        text = await page.text()
    return text.split('name="gprbot-csrf" content="')[1].split('"')[0]


async def test_loopback_console_sets_an_httponly_strict_cookie_and_commands_need_it_and_csrf(tmp_path: Path) -> None:
    async with daemon(tmp_path) as rt, client() as http:
        async with http.post(base(rt) + "/api/command", json={"line": "status"}) as anonymous:
            assert anonymous.status == 401  # a command without the session is refused
        async with http.get(base(rt) + "/") as page:
            cookie = page.cookies[COOKIE_NAME]
            assert cookie["httponly"] and cookie["samesite"] == "Strict" and cookie["path"] == "/"
            assert "frame-ancestors 'none'" in page.headers["Content-Security-Policy"]
            csrf = (await page.text()).split('name="gprbot-csrf" content="')[1].split('"')[0]
        async with http.post(base(rt) + "/api/command", json={"line": "jog 0.1 0 1"}) as no_csrf:
            assert no_csrf.status == 403 and not rt.jog.active
        headers = {CSRF_HEADER: csrf, "Origin": "http://evil.example"}
        async with http.post(base(rt) + "/api/command", json={"line": "jog 0.1 0 1"}, headers=headers) as cross:
            assert cross.status == 403 and not rt.jog.active
        async with http.post(base(rt) + "/api/command", json={"line": "status"}, headers={CSRF_HEADER: csrf}) as ok:
            reply = await ok.json()
            assert ok.status == 200 and reply["ok"] and "mode idle" in reply["body"]
        async with http.post(base(rt) + "/api/command", json={"line": "survey start lines=0"},
                             headers={CSRF_HEADER: csrf}) as bad:
            reply = await bad.json()  # the shell's own grammar validates the parameters
            assert bad.status == 400 and reply["code"] == "bad_argument" and "lines" in reply["text"]
        async with http.post(base(rt) + "/api/command", json={"line": "pull a b"}, headers={CSRF_HEADER: csrf}) as pull:
            assert pull.status == 400 and "Results" in (await pull.json())["text"]


async def test_wrong_token_is_refused_then_throttled_and_no_token_reaches_the_log(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    token_file = tmp_path / "token"
    token = create_token_file(token_file)
    caplog.set_level(logging.DEBUG)
    async with daemon(tmp_path, token_file) as rt, client() as http:
        async with http.get(base(rt) + "/", allow_redirects=False) as page:
            assert page.status == 303 and page.headers["Location"] == "/login"
        async with http.get(base(rt) + "/ws") as ws_anonymous:
            assert ws_anonymous.status == 401
        for attempt in range(5):
            async with http.post(base(rt) + "/login", data={"token": "wrong-" + token[:10]}) as refused:
                assert refused.status == 401, attempt
                assert "Wrong token" in await refused.text()
        async with http.post(base(rt) + "/login", data={"token": token}) as locked:
            assert locked.status == 429  # even the right token waits out the lockout
        assert COOKIE_NAME not in http.cookie_jar.filter_cookies(base(rt))
    assert not any(token in record.getMessage() for record in caplog.records)


async def test_right_token_logs_in_with_a_cookie_and_the_page_works(tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token = create_token_file(token_file)
    async with daemon(tmp_path, token_file) as rt, client() as http:
        async with http.post(base(rt) + "/login", data={"token": token}, allow_redirects=False) as login:
            assert login.status == 303 and login.headers["Location"] == "/"
            assert login.cookies[COOKIE_NAME]["httponly"]
            assert token not in str(login.headers) and token not in login.headers["Location"]
        async with http.get(base(rt) + "/") as page:
            assert page.status == 200 and "E-STOP" in await page.text()
        async with http.get(base(rt) + "/api/runs") as runs:
            assert runs.status == 200 and (await runs.json()) == {"runs": []}


async def test_websocket_refuses_another_origin_and_enforces_the_shells_rate_limit(tmp_path: Path) -> None:
    async with daemon(tmp_path) as rt, client() as http:
        await open_console(http, rt)
        with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
            await http.ws_connect(base(rt) + "/ws", origin="http://evil.example")
        assert refused.value.status == 403
        async with http.ws_connect(base(rt) + "/ws", origin=base(rt)) as ws:
            hello = json.loads((await ws.receive()).data)
            assert hello["type"] == "hello" and hello["jog"]["max_speed_m_s"] == rt.cfg.motion.jog_max_speed_m_s
            assert rt.web is not None
            frozen = time.monotonic() + 100.0
            rt.web.clock = lambda: frozen  # no refill during the burst, however slowly this machine runs
            for i in range(60):
                await ws.send_str(json.dumps({"id": i, "cmd": "status"}))
            codes = []
            async with asyncio.timeout(20):
                while len(codes) < 60:
                    message = json.loads((await ws.receive()).data)
                    if message["type"] == "reply":
                        codes.append(message["code"])
            # the shell's bucket: a burst of its rate (20 commands) passes, the rest is refused
            assert codes.count(None) == 20 and codes.count("rate_limited") == 40, codes


async def test_estop_over_the_socket_latches_and_commands_every_wheel_to_zero(tmp_path: Path) -> None:
    async with daemon(tmp_path) as rt, client() as http:
        await open_console(http, rt)
        assert rt.sim is not None
        async with http.ws_connect(base(rt) + "/ws", origin=base(rt)) as ws:
            await ws.send_str(json.dumps({"id": 1, "cmd": "jog 0.1 0 2"}))
            await ws.send_str(json.dumps({"id": 2, "cmd": "estop"}))
            replies = {}
            async with asyncio.timeout(10):
                while len(replies) < 2:
                    message = json.loads((await ws.receive()).data)
                    if message["type"] == "reply":
                        replies[message["id"]] = message
            assert replies[2]["ok"] and "estop latched" in replies[2]["text"]
            assert rt.estopped
            zeros = {(e.address, e.channel) for e in rt.sim.motors.command_log if e.counts_per_s == 0}
            assert zeros >= set(rt.cfg.motors.wheel_map)
            await ws.send_str(json.dumps({"id": 3, "cmd": "jog 0.1 0 1"}))
            async with asyncio.timeout(10):
                while (message := json.loads((await ws.receive()).data))["type"] != "reply":
                    pass
            assert message["code"] == "estopped"


async def test_estop_over_http_needs_no_login_but_refuses_another_sites_page(tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    create_token_file(token_file)
    async with daemon(tmp_path, token_file) as rt, client() as http:
        async with http.post(base(rt) + "/api/estop", headers={"Origin": "http://evil.example"}) as cross:
            assert cross.status == 403 and not rt.estopped
        async with http.post(base(rt) + "/api/estop") as plain:  # like `estop` in the shell: no auth
            assert plain.status == 200 and (await plain.json())["ok"] and rt.estopped


async def test_a_jog_ends_when_its_socket_closes(tmp_path: Path) -> None:
    async with daemon(tmp_path) as rt, client() as http:
        await open_console(http, rt)
        ws = await http.ws_connect(base(rt) + "/ws", origin=base(rt))
        await ws.send_str(json.dumps({"id": 1, "cmd": "jog 0.05 0 20"}))
        async with asyncio.timeout(10):
            while (message := json.loads((await ws.receive()).data))["type"] != "reply":
                pass
        assert message["ok"] and rt.jog.active
        await ws.close()
        async with asyncio.timeout(2):
            while rt.jog.active:
                await asyncio.sleep(0.01)


async def test_run_files_are_checked_like_the_shells_pull(tmp_path: Path) -> None:
    async with daemon(tmp_path) as rt, client() as http:
        await open_console(http, rt)
        Path(rt.cfg.runs_dir, "r1").mkdir(parents=True)
        Path(rt.cfg.runs_dir, "r1", "a.txt").write_text("x")
        Path(rt.cfg.runs_dir, "secret.txt").write_text("no")
        async with http.get(base(rt) + "/runs/r1/a.txt") as good:
            assert good.status == 200 and await good.text() == "x"
            assert "sandbox" in good.headers["Content-Security-Policy"]
        async with http.get(base(rt) + "/runs/r1/%2E%2E/secret.txt") as escape:
            assert escape.status in (400, 404)
        async with http.get(base(rt) + "/runs/r1/missing.txt") as missing:
            assert missing.status == 404


async def test_a_busy_console_port_is_reported_and_does_not_hold_up_the_daemon(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        async with daemon(tmp_path, web_port=taken.getsockname()[1], wait_for_web=False) as rt:
            assert rt.supervisor is not None
            async with asyncio.timeout(10):
                while not rt.supervisor.ready:  # READY=1 for systemd: every task runs, the console's too
                    await asyncio.sleep(0.05)
            assert rt.web is None and rt.web_error is not None and "cannot listen" in rt.web_error
            assert any(t.name == "web" and t.state == "running" and t.restarts == 0 for t in rt.supervisor.health())


async def test_a_console_beyond_loopback_needs_the_token(tmp_path: Path) -> None:
    cfg = web_config(tmp_path)
    cfg = dataclasses.replace(cfg, web=dataclasses.replace(cfg.web, host="0.0.0.0"))
    runtime = RobotRuntime(cfg, use_worker=False)
    with pytest.raises(ConfigError, match="without a token"):
        await WebConsole(runtime).start()


# ----- the live feed's pure pieces --------------------------------------------------------------------
def test_samples_are_block_averaged_and_traces_stacked_without_losing_the_signal() -> None:
    t = np.arange(512, dtype=np.float32)
    data = np.stack([np.sin(2 * np.pi * t / 64) * (i + 1) for i in range(5)]).astype(np.float32)
    small, factor = decimate_samples(data, 256)
    assert factor == 2 and small.shape == (5, 256)
    np.testing.assert_allclose(small[:, 10], data[:, 20:22].mean(axis=1), rtol=1e-6)
    stacked = stack_traces(data, 2)
    assert stacked.shape == (3, 512)
    np.testing.assert_allclose(stacked[0], (data[0] + data[1]) / 2, rtol=1e-6)
    np.testing.assert_allclose(stacked[2], data[4], rtol=1e-6)  # the last, partial group on its own
    counts, scale = quantise(small)
    np.testing.assert_allclose(counts * scale, small, atol=scale)
    assert np.abs(counts).max() == 32767


def test_section_picture_fits_the_screen_and_keeps_the_peak() -> None:
    image = np.zeros((600, 900), np.float32)
    image[300, 450] = -5.0
    picture = section_picture(image, 320, 160)
    assert picture.shape[0] <= 160 and picture.shape[1] <= 320 and picture.max() == 255
