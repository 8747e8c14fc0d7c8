"""The run log: every raw message that crosses a driver boundary, appended to msgpack segments.

A run directory holds `log-000.msgpack`, `log-001.msgpack`, ... Each segment is a sequence of frames

    magic b"GRL1" | payload length (u32 LE) | CRC-32 of length + payload (u32 LE) | payload

and each payload starts with one kind byte: `H` the header (first record of segment 0; msgpack map),
`M` a message (float64 LE receive time, then `messages.encode` bytes), `E` the end marker (msgpack
map: the run's summary). A frame is one `write` of an unbuffered file, so a killed process leaves at
most one torn frame, which the CRC exposes; `gprbot.runlog_reader.RunLogReader` reads it back.
The writer never reads the clock: receive times, fsync pacing and the header's wall time come in.
"""

from __future__ import annotations

import functools
import os
import struct
import subprocess
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import msgpack

from gprbot import __version__
from gprbot.atomic_files import fsync_directory
from gprbot.config import to_dict
from gprbot.errors import GprbotError
from gprbot.messages import encode

FORMAT = "gprbot-runlog"
VERSION = 1
MAGIC = b"GRL1"
FRAME_HEADER = struct.Struct("<4sII")
RECEIVE_TIME = struct.Struct("<d")
KIND_HEADER, KIND_MESSAGE, KIND_END = b"H", b"M", b"E"
MAX_RECORD_BYTES = 512 * 1024 * 1024  # a length above this is corruption, not a record
SEGMENT_PATTERN = "log-{:03d}.msgpack"
_SECRET_WORDS = ("token", "password", "passwd", "secret", "api_key", "apikey", "private_key", "credential")


def segment_path(run_dir: Path, index: int) -> Path:
    """The path of segment `index` of the run log in run_dir."""
    return run_dir / SEGMENT_PATTERN.format(index)


def frame_crc(payload: bytes | memoryview) -> int:
    """The CRC-32 that protects a frame: over the length field and the payload."""
    return zlib.crc32(payload, zlib.crc32(struct.pack("<I", len(payload))))


def frame(payload: bytes) -> bytes:
    """One framed record ready to append."""
    return FRAME_HEADER.pack(MAGIC, len(payload), frame_crc(payload)) + payload


def is_secret_key(key: object) -> bool:
    """Whether a config key names a secret (token, password, ...) that must not reach a log."""
    return isinstance(key, str) and any(word in key.lower() for word in _SECRET_WORDS)


def without_secrets(value: Any) -> Any:
    """A copy of nested mappings/lists with every secret-named key dropped."""
    if isinstance(value, Mapping):
        return {k: without_secrets(v) for k, v in value.items() if not is_secret_key(k)}
    if isinstance(value, list | tuple):
        return [without_secrets(v) for v in value]
    return value


@functools.cache
def git_commit() -> str:
    """The commit of the gprbot checkout (read once), or "unknown" outside a git checkout."""
    try:
        done = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=Path(__file__).resolve().parent,
            capture_output=True, text=True, timeout=5.0, check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    commit = done.stdout.strip()
    return commit if done.returncode == 0 and commit else "unknown"


def make_run_header(config: Any, created_wall_s: float, devices: Mapping[str, str] | None = None,
                    **extra: Any) -> dict[str, Any]:
    """The header of a run: versions, git commit, creation wall time, resolved config, device ids."""
    return {
        "format": FORMAT,
        "version": VERSION,
        "gprbot_version": __version__,
        "git_commit": git_commit(),
        "created": created_wall_s,
        "config": to_dict(config),
        "devices": dict(devices or {}),
        **extra,
    }


class RunLogWriter:
    """Append-only writer of one run's log (segments, header record, per-record CRC, end marker)."""

    def __init__(self, run_dir: Path, header: Mapping[str, Any], *, segment_bytes: int = 64 * 1024 * 1024,
                 fsync_interval_s: float = 1.0) -> None:
        if segment_bytes <= FRAME_HEADER.size:
            raise GprbotError(f"run log segment_bytes must exceed {FRAME_HEADER.size}, got {segment_bytes}")
        self.run_dir = Path(run_dir)
        self.segment_bytes = segment_bytes
        self.fsync_interval_s = fsync_interval_s
        self.records = 0
        self.bytes_written = 0
        self.segment_index = 0
        self.closed = False
        self._segment_size = 0
        self._last_sync_t: float | None = None
        self._dirty = False
        try:
            self.run_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise GprbotError(f"cannot create run directory {self.run_dir}: {exc.strerror}") from exc
        self._file = self._open_segment(0)
        payload = {**without_secrets(dict(header)), "format": FORMAT, "version": VERSION}
        self._write(KIND_HEADER + msgpack.packb(payload, use_bin_type=True))
        self._sync()

    def append(self, message: Any, t_received: float) -> None:
        """Append one registered message with the monotonic time at which it was received."""
        self._write(KIND_MESSAGE + RECEIVE_TIME.pack(t_received) + encode(message))
        if self._last_sync_t is None:
            self._last_sync_t = t_received
        elif t_received - self._last_sync_t >= self.fsync_interval_s:
            self._sync()
            self._last_sync_t = t_received

    def close(self, summary: Mapping[str, Any]) -> None:
        """Write the end marker with the run's summary, fsync and close (idempotent)."""
        if self.closed:
            return
        self._write(KIND_END + msgpack.packb(without_secrets(dict(summary)), use_bin_type=True))
        self._sync()
        self._file.close()
        self.closed = True

    def abandon(self) -> None:
        """Close without an end marker (the log then reads as not ended, like after a crash)."""
        if not self.closed:
            self._sync()
            self._file.close()
            self.closed = True

    def _open_segment(self, index: int) -> Any:
        path = segment_path(self.run_dir, index)
        try:
            handle = open(path, "xb", buffering=0)  # noqa: SIM115 - lives as long as the segment
            fsync_directory(self.run_dir)
        except FileExistsError as exc:
            raise GprbotError(f"{path} already exists: give every run a new run directory") from exc
        except OSError as exc:
            raise GprbotError(f"cannot create run log segment {path}: {exc.strerror}") from exc
        self.segment_index = index
        self._segment_size = 0
        return handle

    def _write(self, payload: bytes) -> None:
        if self.closed:
            raise GprbotError("the run log is closed; open a new RunLogWriter for a new run")
        data = frame(payload)
        if self._segment_size and self._segment_size + len(data) > self.segment_bytes:
            self._sync()
            self._file.close()
            self._file = self._open_segment(self.segment_index + 1)
        view = memoryview(data)
        try:
            while view:
                view = view[self._file.write(view):]
        except OSError as exc:
            raise GprbotError(
                f"cannot append to the run log in {self.run_dir}: {exc.strerror}; free disk space or stop the run"
            ) from exc
        self._segment_size += len(data)
        self.bytes_written += len(data)
        self.records += 1
        self._dirty = True

    def _sync(self) -> None:
        if self._dirty:
            try:
                os.fsync(self._file.fileno())
            except OSError as exc:
                raise GprbotError(f"cannot fsync the run log in {self.run_dir}: {exc.strerror}") from exc
            self._dirty = False
