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
