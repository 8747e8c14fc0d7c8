"""Sans-IO framing of the SPIDAR NIC-500's data socket in SDK mode (no I/O, no clock).

The socket carries a byte stream of traces, each a little-endian header `<LLLLHH` (tv_sec, tv_nsec,
trace number, status, stacks, header size) followed by float32 samples in mV. `TraceStreamParser`
frames it, checks every frame for plausibility and resynchronises on garbage.

Source: the vendor's public SDK docs (github.com/SensoftInc/spidar-sdk: gpr_data_format, glossary).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

HEADER = struct.Struct("<LLLLHH")
HEADER_SIZE = HEADER.size  # "currently fixed at 20 bytes" (docs)
# The docs say later firmware may grow the header (readers skip unknown fields): accept up to this.
MAX_HEADER_SIZE = 64
# Status is "not used" in SDK mode and documented as a 2-byte field inside a 4-byte slot: any of the
# upper 16 bits set means corruption.
MAX_STATUS = 0xFFFF
VALID_STACKS = frozenset(1 << k for k in range(16))  # point_stacks: a power of 2 in 1..32768 (docs)
MAX_ABS_SAMPLE_MV = 1.0e5  # no receiver delivers 100 V; garbage read as float32 often does
NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class TraceFrame:
    """One trace as the NIC sent it; `sequence` keeps numbers increasing across device restarts."""

    tv_sec: int
    tv_nsec: int
    number: int
    status: int
    stacks: int
    header_size: int
    samples: NDArray[np.float32]
    sequence: int

    @property
    def device_time_s(self) -> float:
        """The NIC's timestamp (its real-time clock, seconds since 1970, stamped at trace request)."""
        return self.tv_sec + self.tv_nsec * 1e-9


@dataclass(frozen=True)
class Resync:
    """Corrupt bytes at stream offset `offset`: the parser scans forward for a plausible header."""

    offset: int
    reason: str


@dataclass(frozen=True)
class TraceGap:
    """Trace numbers strictly between `after` and `number` never arrived (counted as drops)."""

    after: int
    number: int

    @property
    def missing(self) -> int:
        """How many traces are missing."""
        return self.number - self.after - 1


@dataclass(frozen=True)
class DuplicateTrace:
    """A trace whose number was already delivered; it is discarded."""

    number: int


TraceEvent = TraceFrame | Resync | TraceGap | DuplicateTrace


def encode_frame(
    number: int,
    samples: NDArray[np.float32],
    tv_sec: int = 0,
    tv_nsec: int = 0,
    stacks: int = 1,
    status: int = 0,
) -> bytes:
    """The bytes of one trace as the NIC sends it (used by the emulator)."""
    payload = np.ascontiguousarray(samples, dtype="<f4").tobytes()
    return HEADER.pack(tv_sec, tv_nsec, number, status, stacks, HEADER_SIZE) + payload


class TraceCounter:
    """Trace-number bookkeeping shared by successive connections: drops, duplicates, sequence.

    The NIC numbers traces from 1 after each setup. `new_epoch()` (called when we send a setup) keeps
    `sequence` increasing across such restarts, so a number already delivered is never delivered again.
    """

    def __init__(self) -> None:
        self.last_number: int | None = None  # None: unknown, the first trace seen opens the count
        self.last_sequence = 0
        self.drops = 0
        self.duplicates = 0
        self._base = 0

    def new_epoch(self) -> None:
        """The NIC's numbering restarts at 1 (a setup was sent)."""
        self._base = self.last_sequence
        self.last_number = 0

    def admit(self, number: int, events: list[TraceEvent]) -> int | None:
        """The sequence number for trace `number`, or None for a duplicate; appends gap events."""
        last = self.last_number
        if last is not None and number <= last:
            self.duplicates += 1
            events.append(DuplicateTrace(number))
            return None
        if last is not None and number > last + 1:
            gap = TraceGap(last, number)
            self.drops += gap.missing
            events.append(gap)
        self.last_number = number
        self.last_sequence = self._base + number
        return self.last_sequence


class _Header(NamedTuple):
    tv_sec: int
    tv_nsec: int
    number: int
    status: int
    stacks: int
    header_size: int


class _Pending(NamedTuple):
    header: _Header
    samples: NDArray[np.float32]
    length: int


class _ScanIndex(NamedTuple):
    candidates: NDArray[np.intp]  # buffer positions whose bytes could start a plausible header
    bad_prefix: tuple[NDArray[np.int64], ...]  # per alignment a: count of bad floats at a, a+4, ... before k


class TraceStreamParser:
    """Frames the data socket's byte stream into traces, resynchronising after corrupt bytes.

    A frame is plausible when its header is (tv_nsec < 1e9, number >= 1, status < 2**16, stacks a power
    of two — or equal to `stacks` when given — and 20 <= header size <= 64, 4-aligned) and its samples are
    finite and within ±1e5 mV. A frame is delivered only once the bytes after it start with a plausible
    header of a higher number and the same header size and stacks (or the stream ends right after it and it
    directly follows the last frame delivered, numbered next), so an insertion or deletion inside a frame is caught
    even when the frame itself looks fine; when the next number is not higher, one of the two is corrupt and both
    frames are dropped; when its layout differs, the frame is dropped and the next one judged on its own.
    The price: a good frame directly followed by garbage or a corrupt header is dropped too (the cases
    look alike), and each trace is delivered one trace period late. On corruption the parser scans
    forward from the rejected frame's second byte for the next plausible header; `resyncs` counts such
    episodes and `bytes_skipped` the bytes lost (with a torn tail at close).

    What cannot be caught: a byte changed in place inside the samples that leaves them finite and in
    range is indistinguishable from data; so is a changed timestamp or status.
    """

    def __init__(self, points_per_trace: int, stacks: int | None = None, counter: TraceCounter | None = None):
        if points_per_trace < 1:
            raise ValueError(f"points_per_trace must be >= 1, got {points_per_trace}")
        self.points_per_trace = points_per_trace
        self.stacks = stacks
        self.counter = counter if counter is not None else TraceCounter()
        self.resyncs = 0
        self.bytes_skipped = 0
        self._buf = bytearray()
        self._pos = 0  # read position in _buf
        self._offset = 0  # stream offset of _buf[0]
        self._pending: _Pending | None = None  # parsed frame at _pos, awaiting the next header
        self._scanning = False  # inside a resync episode
        self._index: _ScanIndex | None = None  # built at the first resync of a feed, dropped after it

    @property
    def drops(self) -> int:
        """Traces known to be missing from gaps in the trace numbers."""
        return self.counter.drops

    def feed(self, data: bytes) -> list[TraceEvent]:
        """Add bytes from the socket; return the events they complete."""
        self._index = None
        self._buf += data
        events: list[TraceEvent] = []
        try:
            self._advance(events, at_eof=False)
        finally:
            self._index = None  # it holds views of the buffer, which must be resizable again
        if self._pos:
            del self._buf[: self._pos]
            self._offset += self._pos
            self._pos = 0
        return events

    def close(self) -> list[TraceEvent]:
        """End of stream: deliver the last frame if a header confirms it, or it ends the stream and its
        number directly follows the last one delivered; count the rest as skipped."""
        events: list[TraceEvent] = []
        try:
            self._advance(events, at_eof=True)
        finally:
            self._index = None
        self.bytes_skipped += len(self._buf) - self._pos
        self._offset += len(self._buf)
        self._buf.clear()
        self._pos = 0
        self._pending = None
        return events

    def _advance(self, events: list[TraceEvent], at_eof: bool) -> None:
        while True:
            avail = len(self._buf) - self._pos
            if self._pending is None:
                if avail < HEADER_SIZE:
                    return
                header = self._header_at(self._pos)
                if header is None:
                    if not self._resync(events, "implausible header", self._pos + 1):
                        return
                    continue
                length = header.header_size + 4 * self.points_per_trace
                if avail < length:
                    return
                if not self._samples_plausible(self._pos + header.header_size):
                    if not self._resync(events, "non-finite or absurd samples", self._pos + 1):
                        return
                    continue
                samples = np.frombuffer(
                    self._buf, dtype="<f4", count=self.points_per_trace, offset=self._pos + header.header_size
                ).astype(np.float32)
                self._pending = _Pending(header, samples, length)
            pending = self._pending
            after = avail - pending.length
            if after >= HEADER_SIZE:
                following = self._header_at(self._pos + pending.length)
                if following is None:
                    self._pending = None
                    if not self._resync(events, "frame not followed by a plausible header", self._pos + 1):
                        return
                    continue
                if following.number <= pending.header.number:
                    # One of the two numbers is corrupt and nothing tells which: drop both frames.
                    self._pending = None
                    reason = f"trace {following.number} after trace {pending.header.number}"
                    if not self._resync(events, reason, self._pos + pending.length + 1):
                        return
                    continue
                if (following.header_size, following.stacks) != (pending.header.header_size, pending.header.stacks):
                    # A stream's header layout and stacking are fixed by its setup. A header size corrupted to a
                    # larger valid one makes the frame's "extra header" swallow its own samples and take the next
                    # frame's as its own, and the frame after that still confirms it: one of the two is corrupt.
                    self._pending = None
                    reason = (f"trace {pending.header.number} has header size {pending.header.header_size} and "
                              f"{pending.header.stacks} stacks, the next frame {following.header_size} and "
                              f"{following.stacks}")
                    if not self._resync(events, reason, self._pos + 1):
                        return
                    continue
            elif not at_eof:
                return
            elif after or not self._verified_last(pending.header.number):
                # The stream ended and nothing confirms this frame: its number must follow the last one,
                # and no stray bytes may follow it (a torn header, or the frame's own shifted tail).
                self._pending = None
                return
            self._emit(pending, events)

    def _verified_last(self, number: int) -> bool:
        """An unconfirmed last frame counts only if it directly follows a delivered one, numbered next."""
        last = self.counter.last_number
        return not self._scanning and (last is None or number == last + 1)

    def _emit(self, pending: _Pending, events: list[TraceEvent]) -> None:
        h = pending.header
        self._pending = None
        self._pos += pending.length
        self._scanning = False
        sequence = self.counter.admit(h.number, events)
        if sequence is not None:
            events.append(TraceFrame(h.tv_sec, h.tv_nsec, h.number, h.status, h.stacks, h.header_size,
                                     pending.samples, sequence))

    def _resync(self, events: list[TraceEvent], reason: str, start: int) -> bool:
        """Skip to the next plausible header from `start`; False when none is in the buffer yet."""
        if not self._scanning:
            self._scanning = True
            self.resyncs += 1
            events.append(Resync(self._offset + self._pos, reason))
        found = self._scan(start)
        if found is None:
            found = max(start, len(self._buf) - (HEADER_SIZE - 1))  # keep a possible header start
        self.bytes_skipped += found - self._pos
        self._pos = found
        return len(self._buf) - found >= HEADER_SIZE

    def _scan(self, start: int) -> int | None:
        """The first position >= start holding a plausible header (from the buffer's candidate index)."""
        index = self._index if self._index is not None else self._build_index()
        candidates = index.candidates
        at = int(np.searchsorted(candidates, start))
        while at < len(candidates):
            position = int(candidates[at])
            if self._header_at(position) is not None:
                return position
            at += 1
        return None

    def _build_index(self) -> _ScanIndex:
        """Candidate header positions and per-alignment counts of bad floats, once per feed: every
        resync inside that feed is then a search, so garbage costs work linear in its length."""
        chunk = np.frombuffer(self._buf, dtype=np.uint8)
        n = max(0, len(chunk) - (HEADER_SIZE - 1))
        word = chunk.astype(np.uint16)
        header_size = word[18 : 18 + n] | (word[19 : 19 + n] << 8)
        stacks = word[16 : 16 + n] | (word[17 : 17 + n] << 8)
        mask = (chunk[14 : 14 + n] == 0) & (chunk[15 : 15 + n] == 0)
        mask &= (header_size >= HEADER_SIZE) & (header_size <= MAX_HEADER_SIZE) & (header_size % 4 == 0)
        if self.stacks is not None:
            mask &= stacks == self.stacks
        else:
            mask &= (stacks != 0) & ((stacks & (stacks - 1)) == 0)
        bad_prefix = []
        for alignment in range(4):
            count = max(0, (len(chunk) - alignment) // 4)
            floats = np.frombuffer(self._buf, dtype="<f4", count=count, offset=alignment) if count else np.zeros(0)
            bad = ~(np.abs(floats) <= MAX_ABS_SAMPLE_MV)  # also true for NaN
            bad_prefix.append(np.concatenate(([0], np.cumsum(bad, dtype=np.int64))))
        self._index = _ScanIndex(np.flatnonzero(mask), tuple(bad_prefix))
        return self._index

    def _samples_plausible(self, start: int) -> bool:
        """Whether the points_per_trace float32 samples at buffer position `start` are finite and in range."""
        if self._index is not None:  # inside a resync: O(1) from the prefix counts
            prefix = self._index.bad_prefix[start % 4]
            first = start // 4
            if first + self.points_per_trace < len(prefix):
                return bool(prefix[first + self.points_per_trace] == prefix[first])
        samples = np.frombuffer(self._buf, dtype="<f4", count=self.points_per_trace, offset=start)
        return bool(np.all(np.abs(samples) <= MAX_ABS_SAMPLE_MV))  # also false for NaN

    def _header_at(self, position: int) -> _Header | None:
        h = _Header(*HEADER.unpack_from(self._buf, position))
        if h.tv_nsec >= NS_PER_S or h.number == 0 or h.status > MAX_STATUS:
            return None
        if not (HEADER_SIZE <= h.header_size <= MAX_HEADER_SIZE) or h.header_size % 4:
            return None
        stacks_ok = h.stacks == self.stacks if self.stacks is not None else h.stacks in VALID_STACKS
        return h if stacks_ok else None
