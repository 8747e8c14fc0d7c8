"""Files that survive a crash: written through a temp file beside the target, fsynced, then renamed over it."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

OUTPUT_MODE = 0o640  # results are for the operator's group too (mkstemp alone would leave them 0600)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: int = OUTPUT_MODE) -> Iterator[BinaryIO]:
    """Open a temp file beside `path` for binary writing; it replaces `path` only if the block succeeds.

    A reader (or a crash) never sees a half-written file: either the old file or the complete new one;
    the directory is fsynced after the rename, so after a power loss the new name is there too.
    """
    target = Path(path)
    fd, tmp_name = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, target)
        fsync_directory(target.parent)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        raise


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes, mode: int = OUTPUT_MODE) -> None:
    """Write bytes to path atomically."""
    with atomic_open(path, mode) as handle:
        handle.write(data)


def fsync_directory(path: str | os.PathLike[str]) -> None:
    """Make a directory's entries (a rename, a new file) durable."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
