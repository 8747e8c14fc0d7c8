"""Sans-IO protocol of the Sensors & Software SPIDAR NIC-500 in "SDK mode" (no I/O, no clock).

Two halves:
* the data socket: a byte stream of traces, each a little-endian header `<LLLLHH` (tv_sec, tv_nsec,
  trace number, status, stacks, header size) followed by float32 samples in mV. `TraceStreamParser`
  frames it, checks every frame for plausibility and resynchronises on garbage;
* the control API: HTTP/1.1 GET/PUT on port 8080, PUT bodies form-encoded as `data=<json>`, replies
  `{"data": ..., "status": {"status_code", "message", "type"}, "success": bool}`.

Source: the vendor's public SDK docs and examples (github.com/SensoftInc/spidar-sdk: gpr_data_format,
nic_setup, nic_power, nic_acquisition, glossary). Where they are silent, the choice is a constant here.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple
from urllib.parse import urlencode

import numpy as np
from numpy.typing import NDArray

from gprbot.config import GprDeviceConfig
from gprbot.errors import DriverError, ProtocolError

# ---- trace stream -------------------------------------------------------------------------------

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


class TraceStreamParser:
    """Frames the data socket's byte stream into traces, resynchronising after corrupt bytes.

    A frame is plausible when its header is (tv_nsec < 1e9, number >= 1, status < 2**16, stacks a power
    of two — or equal to `stacks` when given — and 20 <= header size <= 64, 4-aligned) and its samples are
    finite and within ±1e5 mV. A frame is delivered only once the bytes after it start with a plausible
    header of a higher number (or the stream ends right after it and it directly follows the last frame
    delivered, numbered next), so an insertion or deletion inside a frame is caught even when the frame itself looks
    fine; when the next number is not higher, one of the two is corrupt and both frames are dropped.
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

    @property
    def drops(self) -> int:
        """Traces known to be missing from gaps in the trace numbers."""
        return self.counter.drops

    def feed(self, data: bytes) -> list[TraceEvent]:
        """Add bytes from the socket; return the events they complete."""
        self._buf += data
        events: list[TraceEvent] = []
        self._advance(events, at_eof=False)
        if self._pos:
            del self._buf[: self._pos]
            self._offset += self._pos
            self._pos = 0
        return events

    def close(self) -> list[TraceEvent]:
        """End of stream: deliver the last frame if a header confirms it, or it ends the stream and its
        number directly follows the last one delivered; count the rest as skipped."""
        events: list[TraceEvent] = []
        self._advance(events, at_eof=True)
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
                samples = np.frombuffer(
                    self._buf, dtype="<f4", count=self.points_per_trace, offset=self._pos + header.header_size
                ).astype(np.float32)
                if not np.all(np.abs(samples) <= MAX_ABS_SAMPLE_MV):  # also false for NaN
                    if not self._resync(events, "non-finite or absurd samples", self._pos + 1):
                        return
                    continue
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
        """The first position >= start holding a plausible header, vectorised over the buffer."""
        chunk = np.frombuffer(bytes(self._buf[start:]), dtype=np.uint8)
        n = len(chunk) - (HEADER_SIZE - 1)
        if n <= 0:
            return None
        word = chunk.astype(np.uint16)
        header_size = word[18 : 18 + n] | (word[19 : 19 + n] << 8)
        stacks = word[16 : 16 + n] | (word[17 : 17 + n] << 8)
        mask = (chunk[14 : 14 + n] == 0) & (chunk[15 : 15 + n] == 0)
        mask &= (header_size >= HEADER_SIZE) & (header_size <= MAX_HEADER_SIZE) & (header_size % 4 == 0)
        if self.stacks is not None:
            mask &= stacks == self.stacks
        else:
            mask &= (stacks != 0) & ((stacks & (stacks - 1)) == 0)
        for candidate in np.flatnonzero(mask):
            position = start + int(candidate)
            if self._header_at(position) is not None:
                return position
        return None

    def _header_at(self, position: int) -> _Header | None:
        h = _Header(*HEADER.unpack_from(self._buf, position))
        if h.tv_nsec >= NS_PER_S or h.number == 0 or h.status > MAX_STATUS:
            return None
        if not (HEADER_SIZE <= h.header_size <= MAX_HEADER_SIZE) or h.header_size % 4:
            return None
        stacks_ok = h.stacks == self.stacks if self.stacks is not None else h.stacks in VALID_STACKS
        return h if stacks_ok else None


# ---- HTTP/1.1 (the minimal client side the control API needs) -----------------------------------

MAX_HEAD_BYTES = 16 * 1024
MAX_BODY_BYTES = 1024 * 1024


def build_request(method: str, host: str, port: int, path: str, form: Mapping[str, str] | None = None) -> bytes:
    """An HTTP/1.1 request; a form (PUT) is sent url-encoded, as the vendor's examples do."""
    lines = [f"{method} {path} HTTP/1.1", f"Host: {host}:{port}", "Accept: application/json",
             "User-Agent: gprbot", "Connection: close"]
    body = b""
    if form is not None:
        body = urlencode(form).encode("ascii")
        lines += ["Content-Type: application/x-www-form-urlencoded", f"Content-Length: {len(body)}"]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("ascii") + body


@dataclass(frozen=True)
class HttpResponse:
    """A complete HTTP response: status code, reason, headers (lower-case names) and body."""

    status: int
    reason: str
    headers: Mapping[str, str]
    body: bytes


class HttpResponseParser:
    """Incremental HTTP/1.1 response reader: Content-Length, chunked, or a body ending at close."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._head: tuple[int, str, dict[str, str]] | None = None

    def feed(self, data: bytes) -> HttpResponse | None:
        """Add received bytes; the response once it is complete, else None."""
        self._buf += data
        if self._head is None and not self._parse_head():
            return None
        return self._complete(at_eof=False)

    def close(self) -> HttpResponse:
        """The peer closed: the response, or ProtocolError if it was cut short."""
        if self._head is None and not self._parse_head():
            raise ProtocolError(f"connection closed after {len(self._buf)} bytes, before a complete HTTP head")
        response = self._complete(at_eof=True)
        if response is None:
            raise ProtocolError("connection closed before the end of the HTTP body")
        return response

    def _parse_head(self) -> bool:
        while True:
            if len(self._buf) >= 5 and not self._buf.startswith(b"HTTP/"):
                raise ProtocolError(f"not an HTTP response (starts with {bytes(self._buf[:16])!r})")
            end = self._buf.find(b"\r\n\r\n")
            if end < 0:
                if len(self._buf) > MAX_HEAD_BYTES:
                    raise ProtocolError(f"HTTP head longer than {MAX_HEAD_BYTES} bytes")
                return False
            lines = self._buf[:end].decode("latin-1").split("\r\n")
            del self._buf[: end + 4]
            parts = lines[0].split(" ", 2)
            if len(parts) < 2 or parts[0] not in ("HTTP/1.0", "HTTP/1.1") or not parts[1].isdigit():
                raise ProtocolError(f"malformed HTTP status line {lines[0]!r}")
            headers: dict[str, str] = {}
            for line in lines[1:]:
                name, sep, value = line.partition(":")
                if not sep or not name or name != name.strip():
                    raise ProtocolError(f"malformed HTTP header line {line!r}")
                headers[name.lower()] = value.strip()
            status = int(parts[1])
            if 100 <= status < 200:  # an interim reply (100 Continue): the real one follows
                continue
            self._head = (status, parts[2] if len(parts) > 2 else "", headers)
            return True

    def _complete(self, at_eof: bool) -> HttpResponse | None:
        assert self._head is not None
        status, reason, headers = self._head
        if "chunked" in headers.get("transfer-encoding", "").lower():
            body = _decode_chunked(self._buf)
        elif "content-length" in headers:
            text = headers["content-length"]
            if not text.isdigit() or int(text) > MAX_BODY_BYTES:
                raise ProtocolError(f"bad Content-Length {text!r}")
            body = bytes(self._buf[: int(text)]) if len(self._buf) >= int(text) else None
        elif status in (204, 304):
            body = b""
        else:
            body = bytes(self._buf) if at_eof else None
        if len(self._buf) > MAX_BODY_BYTES + MAX_HEAD_BYTES:
            raise ProtocolError(f"HTTP body longer than {MAX_BODY_BYTES} bytes")
        return None if body is None else HttpResponse(status, reason, headers, body)


def _decode_chunked(data: bytearray) -> bytes | None:
    """The body of a chunked transfer, or None while incomplete."""
    out = bytearray()
    pos = 0
    while True:
        eol = data.find(b"\r\n", pos)
        if eol < 0:
            return None
        size_text = data[pos:eol].split(b";")[0].strip()
        try:
            size = int(size_text, 16)
        except ValueError:
            raise ProtocolError(f"bad chunk size {bytes(size_text[:16])!r}") from None
        if size == 0:
            return bytes(out) if data.find(b"\r\n\r\n", eol) >= 0 else None  # after optional trailers
        if len(data) < eol + 2 + size + 2:
            return None
        out += data[eol + 2 : eol + 2 + size]
        pos = eol + 2 + size + 2


# ---- the SDK-mode JSON API ----------------------------------------------------------------------

API_IDENTITY = "NIC-500 SDK"  # data.name of GET /api in SDK mode (vendor examples)
RESOURCE_ROOT = "/api"
RESOURCE_NIC_INFO = "/api/nic/system_information"
RESOURCE_GPR_INFO = "/api/nic/gpr/system_information"
RESOURCE_DATA_SOCKET = "/api/nic/gpr/data_socket"
RESOURCE_DATA_SOCKET_RESET = "/api/nic/gpr/data_socket_reset"
RESOURCE_POWER = "/api/nic/power"
RESOURCE_SETUP = "/api/nic/setup"
RESOURCE_ACQUISITION = "/api/nic/acquisition"
RESOURCE_STATUS = "/api/nic/status"
POWER_NIC_ONLY = 1  # 0 would switch the NIC off too: it could then only be restarted by hand
POWER_ALL_ON = 2
ACQUISITION_STOP = 0  # also resets the trace numbering
ACQUISITION_START = 1
WARNING_CODES = range(900, 1000)  # e.g. 913 "Modified Input": applied after rounding
# Units without a calibrated window_time_shift_reference_ps (pulseEKKO PRO): the vendor's default.
DEFAULT_WINDOW_SHIFT_REFERENCE_PS = -55000.0


class DeviceRejectedError(DriverError):
    """The NIC answered a request with an error status (its status code and message kept)."""

    def __init__(self, resource: str, status_code: int, message: str, http_status: int):
        super().__init__(f"the NIC rejected {resource}: status {status_code} ({message}, HTTP {http_status})")
        self.resource = resource
        self.status_code = status_code
        self.http_status = http_status


@dataclass(frozen=True)
class ApiReply:
    """A successful reply: its data and status (0, or a 9xx warning)."""

    data: Any
    status_code: int
    message: str


def api_form(payload: Mapping[str, Any]) -> dict[str, str]:
    """The PUT body of the API: the JSON payload in the form field `data`."""
    return {"data": json.dumps(payload)}


def parse_api_reply(response: HttpResponse, resource: str) -> ApiReply:
    """Decode the JSON envelope; ProtocolError if it is not one, DeviceRejectedError on an error status."""
    try:
        doc = json.loads(response.body)
    except ValueError as exc:
        raise ProtocolError(f"{resource}: the reply (HTTP {response.status}) is not JSON ({exc})") from exc
    if not isinstance(doc, dict):
        raise ProtocolError(f"{resource}: the reply is JSON but not an object")
    status = doc.get("status")
    code, message, kind = 0, str(doc.get("message", "")), ""
    if isinstance(status, dict):
        raw_code = status.get("status_code", 0)
        if not isinstance(raw_code, int) or isinstance(raw_code, bool):
            raise ProtocolError(f"{resource}: status_code is {raw_code!r}, not an integer")
        code, message, kind = raw_code, str(status.get("message", message)), str(status.get("type", ""))
    failed = (response.status >= 400 or doc.get("success") is False or kind in ("ERROR", "FATAL")
              or (code != 0 and code not in WARNING_CODES))
    if failed:
        raise DeviceRejectedError(resource, code, message or response.reason, response.status)
    return ApiReply(doc.get("data"), code, message)


def _field(data: Any, *path: str) -> Any:
    for key in path:
        if not isinstance(data, dict) or key not in data:
            raise ProtocolError(f"the NIC's reply lacks {'.'.join(path)}")
        data = data[key]
    return data


def parse_identity(data: Any) -> str | None:
    """The API's name (GET /api), or None when the reply has none."""
    name = data.get("name") if isinstance(data, dict) else None
    return name if isinstance(name, str) else None


def parse_state(data: Any) -> int:
    """The `state` of a power or acquisition reply."""
    state = _field(data, "state")
    if not isinstance(state, int):
        raise ProtocolError(f"state is {state!r}, not an integer")
    return state


def parse_data_port(data: Any) -> int:
    """The data socket's TCP port (GET api/nic/gpr/data_socket)."""
    port = _field(data, "data_socket", "port")
    if not isinstance(port, int) or not 0 < port < 65536:
        raise ProtocolError(f"data socket port is {port!r}")
    return port


def parse_window_reference_ps(data: Any) -> float | None:
    """The calibrated window shift placing the first break at point 1, None if the unit has none."""
    gpr = _field(data, "gpr")
    value = gpr.get("window_time_shift_reference_ps") if isinstance(gpr, dict) else None
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        raise ProtocolError(f"window_time_shift_reference_ps is {value!r}") from None


@dataclass(frozen=True)
class AcquisitionSetup:
    """The NIC's acquisition parameters (api/nic/setup), as requested or as applied."""

    points_per_trace: int
    time_sampling_interval_ps: float
    point_stacks: int
    window_time_shift_ps: float
    period_s: float
    trigger_mode: str = "Free"

    @property
    def dt_ns(self) -> float:
        """Sample interval in ns."""
        return self.time_sampling_interval_ps / 1000.0


def _json_number(x: float) -> int | float:
    return int(x) if float(x).is_integer() else x  # the API documents integers for ps values


def setup_from_config(cfg: GprDeviceConfig, reference_ps: float | None) -> AcquisitionSetup:
    """The setup to send: `window_shift_ns` is relative to the unit's calibrated reference.

    The reference places the first break at point 1; shifting the window by -1 ns puts it 1 ns into
    the trace (the vendor's examples do the same with a number of points).
    """
    reference = DEFAULT_WINDOW_SHIFT_REFERENCE_PS if reference_ps is None else reference_ps
    return AcquisitionSetup(
        points_per_trace=cfg.points_per_trace,
        time_sampling_interval_ps=cfg.time_sampling_interval_ps,
        point_stacks=cfg.stacks,
        window_time_shift_ps=5 * round((reference + cfg.window_shift_ns * 1000.0) / 5),  # 5 ps steps
        period_s=cfg.trigger_period_s,
    )


def first_break_ns(setup: AcquisitionSetup, reference_ps: float | None) -> float:
    """Where the first break (time zero) lies in each trace, in ns after sample 0."""
    reference = DEFAULT_WINDOW_SHIFT_REFERENCE_PS if reference_ps is None else reference_ps
    return (reference - setup.window_time_shift_ps) / 1000.0


def setup_payload(setup: AcquisitionSetup) -> dict[str, Any]:
    """The JSON of PUT api/nic/setup."""
    return {
        "gpr0": {"parameters": {
            "points_per_trace": setup.points_per_trace,
            "time_sampling_interval_ps": _json_number(setup.time_sampling_interval_ps),
            "point_stacks": setup.point_stacks,
            "window_time_shift_ps": _json_number(setup.window_time_shift_ps),
            "trigger_mode": setup.trigger_mode,
        }},
        "timer": {"parameters": {"period_s": setup.period_s}},
    }


def parse_setup(data: Any) -> AcquisitionSetup:
    """The setup in a reply of api/nic/setup (the docs show the GPR both as "gpr0" and "gpr")."""
    gpr_key = "gpr0" if isinstance(data, dict) and "gpr0" in data else "gpr"
    gpr = _field(data, gpr_key, "parameters")
    timer = _field(data, "timer", "parameters")
    try:
        return AcquisitionSetup(
            points_per_trace=int(gpr["points_per_trace"]),
            time_sampling_interval_ps=float(gpr["time_sampling_interval_ps"]),
            point_stacks=int(gpr["point_stacks"]),
            window_time_shift_ps=float(gpr["window_time_shift_ps"]),
            period_s=float(timer["period_s"]),
            trigger_mode=str(gpr.get("trigger_mode", "Free")),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ProtocolError(f"the NIC's setup reply is incomplete or malformed ({exc!r})") from exc
