"""Browser sessions of the web console: the login cookie, its CSRF token, rate limits, login throttling.

A session is issued after the shell's token is given on the login form (or at once on a loopback
console without a token, as the shell does). The browser holds only a random session id in an
`HttpOnly; SameSite=Strict` cookie; the token itself is never stored, echoed or logged. Each state-
changing request must also carry the session's CSRF token in a header, which another site's page
cannot set (and cannot read, the page being same-origin only).
"""

from __future__ import annotations

import hmac
import itertools
import secrets
from collections.abc import Callable
from dataclasses import dataclass

from aiohttp import web

from gprbot.shell.handler import SessionInfo
from gprbot.shell.session import RateLimiter

COOKIE_NAME = "gprbot_session"
CSRF_HEADER = "X-Gprbot-CSRF"
MAX_SESSIONS = 64  # the oldest login is dropped beyond this
WEB_SESSION_IDS = itertools.count(1_000_001)  # shell TCP sessions count from 1, serial from -1


@dataclass
class WebSession:
    """One logged-in browser: the shell-style SessionInfo the robot handler sees, CSRF token, limits."""

    key: str
    csrf: str
    info: SessionInfo
    rate: RateLimiter
    expires_t: float
    sockets: int = 0


class SessionStore:
    """The live sessions, keyed by their cookie value; expired ones are forgotten on lookup."""

    def __init__(self, ttl_s: float, rate_per_s: float, clock: Callable[[], float]) -> None:
        self.ttl_s, self.rate_per_s, self._clock = ttl_s, rate_per_s, clock
        self._sessions: dict[str, WebSession] = {}

    def __len__(self) -> int:
        return len(self._sessions)

    def create(self, peer: str) -> WebSession:
        """A new session for `peer` (an address, for the logs and the handler)."""
        now = self._clock()
        if len(self._sessions) >= MAX_SESSIONS:
            oldest = min(self._sessions.values(), key=lambda s: s.expires_t)
            self._sessions.pop(oldest.key, None)
        session = WebSession(secrets.token_urlsafe(32), secrets.token_urlsafe(24),
                             SessionInfo(next(WEB_SESSION_IDS), "web", peer, authenticated=True),
                             RateLimiter(self.rate_per_s, now), now + self.ttl_s)
        self._sessions[session.key] = session
        return session

    def get(self, key: str | None) -> WebSession | None:
        """The session of a cookie value, if it exists and has not expired."""
        if not key:
            return None
        session = self._sessions.get(key)
        if session is None:
            return None
        if self._clock() >= session.expires_t:
            del self._sessions[key]
            return None
        return session

    def drop(self, key: str) -> None:
        """Log a session out."""
        self._sessions.pop(key, None)


def same_origin(request: web.Request, *, required: bool) -> bool:
    """Whether the request's Origin is this console's; without one: `not required` (curl sends none,
    browsers always send it on POST and WebSocket requests)."""
    origin = request.headers.get("Origin")
    if origin is None:
        return not required
    return origin == f"{request.scheme}://{request.host}"


def csrf_matches(session: WebSession, given: str | None) -> bool:
    """Constant-time check of the CSRF header against the session's token."""
    return given is not None and hmac.compare_digest(session.csrf.encode(), given.encode())


class LoginThrottle:
    """Per-address login failures: after `max_failures` the address waits `lockout_s` before trying again."""

    def __init__(self, max_failures: int, lockout_s: float, clock: Callable[[], float]) -> None:
        self.max_failures, self.lockout_s, self._clock = max_failures, lockout_s, clock
        self._failures: dict[str, tuple[int, float]] = {}

    def locked_for_s(self, peer: str) -> float:
        """Seconds `peer` must still wait (0 when it may try)."""
        count, since = self._failures.get(peer, (0, 0.0))
        if count < self.max_failures:
            return 0.0
        left = since + self.lockout_s - self._clock()
        if left <= 0:
            del self._failures[peer]
            return 0.0
        return left

    def failed(self, peer: str) -> int:
        """Count one failure; the number so far."""
        count, _ = self._failures.get(peer, (0, 0.0))
        self._failures[peer] = (count + 1, self._clock())
        return count + 1

    def succeeded(self, peer: str) -> None:
        """Forget `peer`'s failures."""
        self._failures.pop(peer, None)
