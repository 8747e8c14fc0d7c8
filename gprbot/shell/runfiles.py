"""The run directories as the shell serves them: list runs and files, open a file for `pull` safely."""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from gprbot.shell.commands import CommandError, ErrorCode

MAX_LISTED = 10000
_HASH_CHUNK = 1 << 20


@dataclass
class OpenedFile:
    """A run file opened for `pull`: its size and sha256 fixed at open time, read from `handle`."""

    path: Path
    handle: BinaryIO
    size: int
    sha256: str


def list_runs(runs_dir: Path) -> list[str]:
    """The run directories' names, newest first (an absent runs directory has none)."""
    try:
        entries = [e for e in os.scandir(runs_dir) if e.is_dir(follow_symlinks=False)]
    except FileNotFoundError:
        return []
    entries.sort(key=lambda e: (e.stat(follow_symlinks=False).st_mtime, e.name), reverse=True)
    return [e.name for e in entries[:MAX_LISTED]]


def list_files(runs_dir: Path, run: str) -> list[tuple[str, int]]:
    """(relative path, size) of every regular file of a run, sorted; symlinks are not listed."""
    root = _run_root(runs_dir, run)
    found: list[tuple[str, int]] = []
    for dirpath, dirnames, filenames in os.walk(root):  # os.walk does not follow symlinked dirs
        dirnames.sort()
        for name in sorted(filenames):
            path = Path(dirpath) / name
            if path.is_symlink() or not path.is_file():
                continue
            found.append((path.relative_to(root).as_posix(), path.stat().st_size))
            if len(found) >= MAX_LISTED:
                return found
    return sorted(found)


def open_run_file(runs_dir: Path, run: str, name: str) -> OpenedFile:
    """Open a run's file for reading and hash it; CommandError if it is absent or resolves outside runs_dir."""
    root = _runs_root(runs_dir)
    try:
        resolved = (root / run / name).resolve(strict=True)
    except (FileNotFoundError, NotADirectoryError):
        raise CommandError(ErrorCode.NOT_FOUND, f"no file {name!r} in run {run!r}; see `files {run}`") from None
    except (OSError, RuntimeError) as exc:  # RuntimeError: a symlink loop
        raise CommandError(ErrorCode.BAD_ARGUMENT, f"cannot resolve {name!r}: {exc}") from exc
    if not resolved.is_relative_to(root):
        raise CommandError(ErrorCode.BAD_ARGUMENT, f"{name!r} resolves outside the runs directory; refused")
    if not resolved.is_file():
        raise CommandError(ErrorCode.NOT_FOUND, f"{name!r} in run {run!r} is not a regular file")
    handle = resolved.open("rb")
    try:
        size = os.fstat(handle.fileno()).st_size
        digest = hashlib.sha256()
        left = size
        while left:
            chunk = handle.read(min(_HASH_CHUNK, left))
            if not chunk:
                raise CommandError(ErrorCode.INTERNAL, f"{name!r} shrank while being read; try again")
            digest.update(chunk)
            left -= len(chunk)
        handle.seek(0)
    except BaseException:
        handle.close()
        raise
    return OpenedFile(resolved, handle, size, digest.hexdigest())


def _runs_root(runs_dir: Path) -> Path:
    try:
        return runs_dir.resolve(strict=True)
    except FileNotFoundError:
        raise CommandError(ErrorCode.NOT_FOUND, f"the runs directory {runs_dir} does not exist yet") from None


def _run_root(runs_dir: Path, run: str) -> Path:
    root = _runs_root(runs_dir)
    run_dir = root / run
    if run_dir.is_symlink() or not run_dir.is_dir():
        raise CommandError(ErrorCode.NOT_FOUND, f"no run {run!r}; see `runs`")
    return run_dir
