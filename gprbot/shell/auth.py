"""The shell's shared-secret token: a file only the daemon's user may read, compared in constant time."""

from __future__ import annotations

import hmac
import os
import secrets
import stat
from pathlib import Path

from gprbot.errors import ConfigError

MIN_TOKEN_CHARS = 16


def load_token(path: str | Path) -> str:
    """Read the token; ConfigError if the file is missing, not private (0600), not ours, or too short."""
    path = Path(path)
    try:
        info = path.stat()
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"token file {path} does not exist; create it (see docs/install.md)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read token file {path}: {exc}") from exc
    if not stat.S_ISREG(info.st_mode):
        raise ConfigError(f"token file {path} is not a regular file")
    if info.st_mode & 0o077:
        raise ConfigError(
            f"token file {path} is accessible by group or others (mode {stat.S_IMODE(info.st_mode):04o}); "
            f"run `chmod 600 {path}`"
        )
    if info.st_uid != os.geteuid():
        raise ConfigError(f"token file {path} is owned by uid {info.st_uid}, not by this user ({os.geteuid()})")
    token = text.strip()
    if len(token) < MIN_TOKEN_CHARS or any(ch.isspace() for ch in token):
        raise ConfigError(f"token in {path} must be one word of at least {MIN_TOKEN_CHARS} characters")
    return token


def token_matches(expected: str, given: str) -> bool:
    """Constant-time comparison, so the reply time does not leak how much of a guess was right."""
    return hmac.compare_digest(expected.encode("utf-8"), given.encode("utf-8"))


def create_token_file(path: str | Path) -> str:
    """Write a new random token to `path` (mode 0600, refusing to overwrite); return it."""
    token = secrets.token_urlsafe(32)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        raise ConfigError(f"token file {path} already exists; delete it first to make a new token") from None
    with os.fdopen(fd, "w", encoding="utf-8") as handle:
        handle.write(token + "\n")
    return token


class AuthGuard:
    """Wrong-token accounting across connections: a host that guesses `max_failures` times in a row is
    locked out (30 s, doubling up to 15 min), and all hosts together get `global_per_s` guesses a second.

    Kept by the server, so reconnecting does not reset the count; a correct token clears the host's.
    """

    def __init__(self, max_failures: int = 5, lockout_s: tuple[float, float] = (30.0, 900.0),
                 global_per_s: float = 5.0) -> None:
        self.max_failures = max_failures
        self.lockout_s = lockout_s
        self.global_per_s = global_per_s
        self._failures: dict[str, int] = {}
        self._locked_until: dict[str, float] = {}
        self._lockouts: dict[str, int] = {}
        self._budget = global_per_s
        self._budget_t: float | None = None
        self.refused = 0

    def refusal(self, host: str, now: float) -> str | None:
        """Why an attempt from `host` at `now` is not even compared (locked out, global rate), or None."""
        until = self._locked_until.get(host)
        if until is not None and now < until:
            self.refused += 1
            return f"too many wrong tokens from {host}; locked out for {until - now:.0f} s more"
        if self._budget_t is not None:
            self._budget = min(self.global_per_s, self._budget + (now - self._budget_t) * self.global_per_s)
        self._budget_t = now
        if self._budget < 1.0:
            self.refused += 1
            return "too many wrong tokens on this robot; try again in a few seconds"
        return None

    def failed(self, host: str, now: float) -> bool:
        """Count a wrong token from `host`; True when that locks the host out."""
        self._budget -= 1.0
        count = self._failures.get(host, 0) + 1
        self._failures[host] = count
        if count < self.max_failures:
            return False
        lockouts = self._lockouts.get(host, 0)
        self._lockouts[host] = lockouts + 1
        self._locked_until[host] = now + min(self.lockout_s[0] * 2**lockouts, self.lockout_s[1])
        self._failures[host] = 0
        if len(self._locked_until) > 4096:  # bounded: forget the lockouts that have expired
            self._locked_until = {h: t for h, t in self._locked_until.items() if t > now}
        if len(self._failures) > 4096:
            self._failures = {h: c for h, c in self._failures.items() if h in self._locked_until}
        return True

    def succeeded(self, host: str) -> None:
        """A correct token from `host`: its count of wrong ones starts again."""
        self._failures.pop(host, None)
        self._lockouts.pop(host, None)
