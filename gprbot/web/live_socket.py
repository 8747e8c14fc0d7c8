"""The console's WebSocket: one per browser, the live feed out, shell command lines in.

Accepted only with a session cookie and from the console's own origin (no cross-site WebSocket), up
to the shell's client limit. Outgoing messages wait in a bounded queue drained by the browser's own
sender task, so a slow browser is dropped rather than slowing the others. Incoming `estop` runs the
moment it is read; every other command goes, in order, through a per-browser FIFO (like the shell's).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from typing import TYPE_CHECKING, Any

from aiohttp import WSMsgType, web

from gprbot.shell.protocol import Reply
from gprbot.shell.session import SessionLimits
from gprbot.web.sessions import WebSession, same_origin

if TYPE_CHECKING:
    from gprbot.web.server import WebConsole

log = logging.getLogger(__name__)
CLIENT_QUEUE = 256  # messages waiting for one browser; a browser this far behind is dropped


def reply_record(reply: Reply) -> dict[str, Any]:
    """A shell Reply as JSON for the page."""
    return {"ok": reply.ok, "code": str(reply.code) if reply.code else None, "text": reply.text,
            "body": list(reply.body)}


class Browser:
    """One connected WebSocket: its session and a bounded queue drained by its own sender task."""

    def __init__(self, ws: web.WebSocketResponse, session: WebSession, backlog: int = 0) -> None:
        self.ws, self.session = ws, session
        self.queue: asyncio.Queue[str] = asyncio.Queue(maxsize=CLIENT_QUEUE + backlog)
        self.sender = asyncio.create_task(self._send_loop(), name=f"web-send-{session.info.id}")

    def offer(self, text: str) -> bool:
        """Queue a message; False if the browser is too far behind."""
        try:
            self.queue.put_nowait(text)
        except asyncio.QueueFull:
            return False
        return True

    async def _send_loop(self) -> None:
        with contextlib.suppress(ConnectionError, RuntimeError):
            while True:
                await self.ws.send_str(await self.queue.get())


def parse_socket_command(text: str) -> tuple[Any, str]:
    """A browser's `{"id": N, "cmd": "LINE"}` → (id, line); ValueError with what to send otherwise."""
    try:
        data = json.loads(text)
        line = data["cmd"]
    except (ValueError, KeyError, TypeError):
        raise ValueError('send {"id": N, "cmd": "COMMAND"}') from None
    if not isinstance(line, str):
        raise ValueError("cmd must be a string")
    return data.get("id"), line


async def serve_socket(console: WebConsole, request: web.Request) -> web.StreamResponse:
    """GET /ws: the live socket of one logged-in browser, until it closes."""
    session = console.session_of(request)
    if session is None:
        raise web.HTTPUnauthorized(text="log in first (GET /login)", content_type="text/plain")
    if not same_origin(request, required=True):
        raise web.HTTPForbidden(text="WebSocket from another origin refused", content_type="text/plain")
    if len(console.browsers) >= console.max_clients:
        raise web.HTTPServiceUnavailable(text=f"too many clients (max {console.max_clients}); try again later",
                                         content_type="text/plain")
    ws = web.WebSocketResponse(heartbeat=5.0, max_msg_size=4096)
    await ws.prepare(request)
    run = console.rt.survey.current
    current_line = run.line if run is not None else None
    backlog = [m for m in console.live.backlog if m["type"] != "traces" or m["line"] == current_line]
    browser = Browser(ws, session, len(backlog))
    console.browsers.add(browser)
    for first in [console.live.hello(), *backlog, console.live.status(len(console.browsers))]:
        browser.offer(json.dumps(first))
    commands: asyncio.Queue[tuple[Any, str] | None] = asyncio.Queue(maxsize=SessionLimits().max_pending)
    worker = asyncio.create_task(_command_worker(console, browser, commands))
    log.info("web: %s connected (session %d)", request.remote, session.info.id)
    try:
        async for frame in ws:
            if frame.type != WSMsgType.TEXT:
                continue
            try:
                request_id, line = parse_socket_command(frame.data)
            except ValueError as exc:
                browser.offer(json.dumps({"type": "reply", "id": None, "ok": False, "code": "bad_command",
                                          "text": str(exc), "body": []}))
                continue
            if line.strip().lower() == "estop":  # the fast path: now, ahead of anything queued
                reply = await console.estop(session.info)
                browser.offer(json.dumps({"type": "reply", "id": request_id, **reply_record(reply)}))
            elif (refusal := console.rate_limited(session)) is not None:  # counted on arrival, as the shell does
                browser.offer(json.dumps({"type": "reply", "id": request_id, **reply_record(refusal)}))
            else:
                await commands.put((request_id, line))
    finally:
        console.browsers.discard(browser)
        console.release_jog(session)
        worker.cancel()
        browser.sender.cancel()
        log.info("web: session %d disconnected", session.info.id)
    return ws


async def _command_worker(console: WebConsole, browser: Browser,
                          commands: asyncio.Queue[tuple[Any, str] | None]) -> None:
    while (item := await commands.get()) is not None:
        request_id, line = item
        reply = await console.execute(browser.session, line, counted=True)
        browser.offer(json.dumps({"type": "reply", "id": request_id, **reply_record(reply)}))
