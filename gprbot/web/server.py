"""The operator's web console: aiohttp on the daemon's event loop, one task of the supervisor's table.

Security is the shell's: loopback needs no token; any other bind needs the shell's token file, given
once on the login form, after which the browser holds a session cookie (HttpOnly, SameSite=Strict).
Commands are the shell's own (parsed by its grammar, executed by the same RobotHandler, under the
same per-client rate and client-count limits); each state-changing request carries the session's
CSRF token in a header, and WebSockets are accepted only from the console's own origin. The e-stop,
like the shell's, needs no login: it is executed the moment it is read, ahead of everything queued.
"""

from __future__ import annotations

import asyncio
import contextlib
import html
import json
import logging
import re
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aiohttp import web

from gprbot.errors import ConfigError, GprbotError
from gprbot.shell.auth import load_token, token_matches
from gprbot.shell.commands import (
    CommandError,
    Empty,
    ErrorCode,
    Estop,
    Jog,
    Reset,
    Status,
    Stop,
    SurveyControl,
    SurveyStart,
    parse_command,
)
from gprbot.shell.handler import SessionInfo
from gprbot.shell.protocol import Reply
from gprbot.shell.server import is_loopback
from gprbot.shell.session import SessionLimits
from gprbot.web.live import LiveFeed
from gprbot.web.live_socket import Browser, reply_record, serve_socket
from gprbot.web.run_routes import RunRoutes
from gprbot.web.sessions import (
    COOKIE_NAME,
    CSRF_HEADER,
    LoginThrottle,
    SessionStore,
    WebSession,
    csrf_matches,
    same_origin,
)

if TYPE_CHECKING:
    from gprbot.robot.runtime import RobotRuntime

log = logging.getLogger(__name__)
STATIC_DIR = Path(__file__).parent / "static"
ROBOT_COMMANDS = (Status, Jog, Stop, Reset, SurveyStart, SurveyControl)
HANDLER_TIMEOUT_S = SessionLimits().handler_timeout_s
LOGIN_LOCKOUT_S = 30.0
_HTTP_STATUS = {None: 200, ErrorCode.BAD_COMMAND: 400, ErrorCode.BAD_ARGUMENT: 400, ErrorCode.BUSY: 409,
                ErrorCode.ESTOPPED: 409, ErrorCode.NOT_FOUND: 404, ErrorCode.UNAUTHORIZED: 401,
                ErrorCode.TOO_LONG: 400, ErrorCode.RATE_LIMITED: 429, ErrorCode.INTERNAL: 500}
_CONSOLE_CSP = ("default-src 'self'; img-src 'self' data: blob:; style-src 'self' 'unsafe-inline'; "
                "script-src 'self'; connect-src 'self'; frame-ancestors 'none'; form-action 'self'")
# report.html and other run files: an opaque origin (no cookies, no API), inline scripts for the report
_RUN_FILE_CSP = ("sandbox allow-scripts; default-src 'none'; img-src data: blob:; style-src 'unsafe-inline'; "
                 "script-src 'unsafe-inline' blob:")


class WebConsole:
    """The console's HTTP and WebSocket server and its live feed."""

    def __init__(self, runtime: RobotRuntime, *, token_file: str | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        from gprbot.robot.robot_commands import RobotHandler

        cfg = runtime.cfg
        self.rt, self.web_cfg, self.clock = runtime, cfg.web, clock
        self.host, self.port = cfg.web.host, cfg.web.port
        self.handler = RobotHandler(runtime)
        self.sessions = SessionStore(cfg.web.session_ttl_s, cfg.shell.rate_per_s, clock)
        self.throttle = LoginThrottle(SessionLimits().max_auth_failures, LOGIN_LOCKOUT_S, clock)
        self.live = LiveFeed(runtime)
        self.max_clients = cfg.shell.max_clients
        self._token_file = token_file if token_file is not None else cfg.shell.token_file
        self._token: str | None = None
        self.browsers: set[Browser] = set()
        self._runner: web.AppRunner | None = None
        self._jogger: int | None = None  # the session whose jog is running
        self.last_estop_t: float | None = None  # when the last e-stop reached the console (clock())
        self._unsubscribe: Callable[[], None] | None = None
        self._closing: set[asyncio.Task[Any]] = set()
        self.ticks = 0

    @property
    def url(self) -> str:
        """Where an operator points the browser."""
        host = "127.0.0.1" if self.host in ("", "0.0.0.0", "::") else self.host
        return f"http://{host}:{self.port}/"

    @property
    def browser_count(self) -> int:
        """WebSockets connected now."""
        return len(self.browsers)

    # ----- lifecycle ----------------------------------------------------------------------------
    async def start(self) -> None:
        """Load the token (required beyond loopback), bind, serve; `.port` is then the bound port."""
        if self._token_file is not None:
            self._token = load_token(self._token_file)
        elif not is_loopback(self.host):
            raise ConfigError(f"the web console would listen on {self.host!r} without a token; set "
                              "shell.token_file (mode 0600) or web.host: 127.0.0.1")
        app = web.Application(middlewares=[self._headers], client_max_size=64 * 1024)
        app.add_routes([
            web.get("/", self._index), web.get("/login", self._login_page), web.post("/login", self._login),
            web.post("/logout", self._logout), web.get("/ws", self._websocket),
            web.post("/api/command", self._command), web.post("/api/estop", self._estop),
            *RunRoutes(Path(self.rt.cfg.runs_dir), lambda r: self._authorised(r, unsafe=False)).routes(),
        ])
        app.router.add_static("/static/", STATIC_DIR, follow_symlinks=False)
        runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=1.0)  # no request lines
        await runner.setup()
        try:
            await web.TCPSite(runner, self.host, self.port).start()
        except OSError as exc:
            await runner.cleanup()
            raise ConfigError(f"cannot listen on {self.host}:{self.port} for the web console: {exc}; "
                              "is another gprbot running? (web.port)") from exc
        self._runner = runner
        self.port = int(runner.addresses[0][1])
        self._unsubscribe = self.rt.events.subscribe(self._event)
        log.info("web console on %s (%s)", self.url, "login with the shell token" if self._token else "no token")

    async def close(self) -> None:
        """Close every browser and stop serving."""
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None
        for browser in list(self.browsers):
            browser.sender.cancel()
            with contextlib.suppress(Exception):
                await browser.ws.close()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

    async def run(self, beat: Callable[[], None]) -> None:
        """The console's task: push status and new survey data to every browser, status_hz times a second."""
        period = 1.0 / self.web_cfg.status_hz
        while True:
            beat()
            self.tick()
            await asyncio.sleep(period)

    def _event(self, text: str) -> None:
        """A daemon event line (`line 3 end`, `estop`, ...) to every browser's log."""
        self._broadcast([json.dumps({"type": "event", "text": text})])

    def _broadcast(self, messages: list[str]) -> None:
        for browser in list(self.browsers):
            for text in messages:
                if not browser.offer(text):
                    log.warning("web: %s is not reading; dropping it", browser.session.info.peer)
                    self._drop(browser)
                    break

    def _drop(self, browser: Browser) -> None:
        self.browsers.discard(browser)
        closing = asyncio.create_task(browser.ws.close())
        self._closing.add(closing)
        closing.add_done_callback(self._closing.discard)

    def tick(self) -> None:
        """One push: what the survey produced since the last tick, then a status snapshot."""
        self.ticks += 1
        per_tick = max(1, round(self.web_cfg.max_traces_per_s / self.web_cfg.status_hz))
        messages = [json.dumps(m) for m in self.live.poll(per_tick)]
        messages.append(json.dumps(self.live.status(len(self.browsers))))
        self._broadcast(messages)

    # ----- commands (shared by the WebSocket and POST /api/command) -----------------------------
    def rate_limited(self, session: WebSession) -> Reply | None:
        """The shell's per-client rate limit, counted when a command arrives; the refusal, or None."""
        if session.rate.allow(self.clock()):
            return None
        return Reply.failure(ErrorCode.RATE_LIMITED, f"more than {self.sessions.rate_per_s:g} commands/s; slow down")

    async def execute(self, session: WebSession, line: str, *, counted: bool = False) -> Reply:
        """One shell command line from a logged-in browser: parsed, limited (unless `counted` already on
        arrival) and run like the shell's."""
        try:
            command = parse_command(line)
        except CommandError as exc:
            return Reply.failure(exc.code, exc.text)
        if isinstance(command, Estop):
            return await self.estop(session.info)
        if not counted and (refusal := self.rate_limited(session)) is not None:
            return refusal
        if isinstance(command, Empty):
            return Reply.success()
        if not isinstance(command, ROBOT_COMMANDS):
            return Reply.failure(ErrorCode.BAD_COMMAND, f"{line.split()[0]!r} belongs to the line shell; "
                                 "the console has runs and downloads on its Results page")
        try:
            async with asyncio.timeout(HANDLER_TIMEOUT_S):
                reply = await self.handler.handle(command, session.info)
        except TimeoutError:
            return Reply.failure(ErrorCode.INTERNAL, f"the robot did not answer within {HANDLER_TIMEOUT_S:g} s")
        except GprbotError as exc:
            return Reply.failure(ErrorCode.INTERNAL, str(exc))
        if isinstance(command, Jog) and reply.ok:
            self._jogger = session.info.id
        return reply

    async def estop(self, info: SessionInfo) -> Reply:
        """The shell's e-stop path: wheels commanded to zero now, latched until `reset`."""
        self.last_estop_t = self.clock()
        log.warning("web: estop from %s", info.peer)
        try:
            async with asyncio.timeout(HANDLER_TIMEOUT_S):
                return await self.handler.estop(info)
        except Exception as exc:
            log.critical("web: estop handler failed", exc_info=True)
            return Reply.failure(ErrorCode.INTERNAL, f"estop failed: {exc!r}; use the hardware e-stop")

    def release_jog(self, session: WebSession) -> None:
        """A browser that jogged went away: its jog ends now, not at the dead-man timeout."""
        if self._jogger == session.info.id and self.rt.jog.active:
            self.rt.jog.stop(self.clock())
            log.info("web: jog of session %d stopped (its socket closed)", session.info.id)

    # ----- helpers ------------------------------------------------------------------------------
    @web.middleware
    async def _headers(self, request: web.Request,
                       handler: Callable[[web.Request], Awaitable[web.StreamResponse]]) -> web.StreamResponse:
        response = await handler(request)
        is_run_file = request.path.startswith("/runs/")
        response.headers.setdefault("Content-Security-Policy", _RUN_FILE_CSP if is_run_file else _CONSOLE_CSP)
        response.headers["X-Content-Type-Options"] = "nosniff"
        # not "no-referrer": with it Chromium sends `Origin: null` on same-origin form posts (the login)
        response.headers["Referrer-Policy"] = "same-origin"
        if not is_run_file:
            response.headers["X-Frame-Options"] = "DENY"
        if request.path.startswith(("/api/", "/login")) or request.path == "/":
            response.headers["Cache-Control"] = "no-store"
        return response

    def session_of(self, request: web.Request) -> WebSession | None:
        """The request's live session (from its cookie), if any."""
        return self.sessions.get(request.cookies.get(COOKIE_NAME))

    def _peer(self, request: web.Request) -> str:
        return request.remote or "?"

    def _authorised(self, request: web.Request, *, unsafe: bool) -> WebSession:
        """The request's session; raises 401 without one, 403 when a state change lacks CSRF proof."""
        session = self.session_of(request)
        if session is None:
            raise web.HTTPUnauthorized(text="log in first (GET /login)", content_type="text/plain")
        if unsafe and not (same_origin(request, required=False)
                           and csrf_matches(session, request.headers.get(CSRF_HEADER))):
            raise web.HTTPForbidden(text=f"missing or wrong {CSRF_HEADER} header; reload the console",
                                    content_type="text/plain")
        return session

    def _set_cookie(self, response: web.StreamResponse, session: WebSession) -> None:
        response.set_cookie(COOKIE_NAME, session.key, max_age=int(self.web_cfg.session_ttl_s), path="/",
                            httponly=True, samesite="Strict")

    def _page(self, name: str, **values: str) -> str:
        text = (STATIC_DIR / name).read_text(encoding="utf-8")
        return re.sub(r"\{\{(\w+)\}\}", lambda m: html.escape(values[m.group(1)]), text)

    # ----- pages and login ----------------------------------------------------------------------
    async def _index(self, request: web.Request) -> web.StreamResponse:
        session = self.session_of(request)
        fresh = session is None and self._token is None
        if fresh:  # loopback without a token: like the shell, no login
            session = self.sessions.create(self._peer(request))
        if session is None:
            raise web.HTTPSeeOther("/login")
        response = web.Response(text=self._page("index.html", csrf=session.csrf), content_type="text/html")
        if fresh:
            self._set_cookie(response, session)
        return response

    async def _login_page(self, request: web.Request, message: str = "", status: int = 200) -> web.StreamResponse:
        if self._token is None:
            raise web.HTTPSeeOther("/")
        html = self._page("login.html", message=message)
        return web.Response(text=html, content_type="text/html", status=status)

    async def _login(self, request: web.Request) -> web.StreamResponse:
        peer = self._peer(request)
        if self._token is None:
            raise web.HTTPSeeOther("/")
        if not same_origin(request, required=False):
            raise web.HTTPForbidden(text="login from another site refused", content_type="text/plain")
        wait_s = self.throttle.locked_for_s(peer)
        if wait_s > 0:
            return await self._login_page(request, f"Too many wrong tokens; wait {wait_s:.0f} s.", 429)
        form = await request.post()
        given = form.get("token")
        if not isinstance(given, str) or not token_matches(self._token, given.strip()):
            count = self.throttle.failed(peer)
            log.warning("web: bad token from %s (%d)", peer, count)
            return await self._login_page(request, "Wrong token.", 401)
        self.throttle.succeeded(peer)
        session = self.sessions.create(peer)
        log.info("web: %s logged in (session %d)", peer, session.info.id)
        response = web.HTTPSeeOther("/")
        self._set_cookie(response, session)
        raise response

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        return await serve_socket(self, request)

    async def _logout(self, request: web.Request) -> web.StreamResponse:
        session = self._authorised(request, unsafe=True)
        self.sessions.drop(session.key)
        response = web.json_response({"ok": True})
        response.del_cookie(COOKIE_NAME, path="/")
        return response

    # ----- the API ------------------------------------------------------------------------------
    async def _command(self, request: web.Request) -> web.StreamResponse:
        session = self._authorised(request, unsafe=True)
        try:
            line = (await request.json())["line"]
            if not isinstance(line, str):
                raise TypeError
        except (ValueError, KeyError, TypeError):
            return web.json_response({"ok": False, "code": "bad_command", "text": 'send {"line": "COMMAND"}'},
                                     status=400)
        reply = await self.execute(session, line)
        return web.json_response(reply_record(reply), status=_HTTP_STATUS.get(reply.code, 500))

    async def _estop(self, request: web.Request) -> web.StreamResponse:
        if not same_origin(request, required=False):
            raise web.HTTPForbidden(text="e-stop from another site's page refused", content_type="text/plain")
        session = self.session_of(request)
        info = session.info if session else SessionInfo(0, "web", self._peer(request), authenticated=False)
        reply = await self.estop(info)
        return web.json_response(reply_record(reply), status=200 if reply.ok else 500)


async def serve_console(runtime: RobotRuntime, beat: Callable[[], None], *, token_file: str | None = None,
                        retry_s: float = 5.0) -> None:
    """The daemon's `web` task. The console is not critical: a port in use or a refused config is logged
    (once per distinct reason) and retried here, so that it never holds up READY=1 or the robot."""
    last_error = ""
    while True:
        console = WebConsole(runtime, token_file=token_file)
        try:
            await console.start()
        except ConfigError as exc:
            if str(exc) != last_error:
                log.error("web console not started: %s; retrying every %g s", exc, retry_s)
                last_error = str(exc)
            runtime.web_error = str(exc)
            for _ in range(max(1, round(retry_s / 0.5))):
                beat()
                await asyncio.sleep(0.5)
            continue
        runtime.web, runtime.web_error = console, None
        try:
            await console.run(beat)
        finally:
            runtime.web = None
            await console.close()
