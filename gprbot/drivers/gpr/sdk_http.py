"""Sans-IO HTTP/1.1: the minimal client side the NIC-500's control API needs (no I/O, no clock)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from urllib.parse import urlencode

from gprbot.errors import ProtocolError

MAX_HEAD_BYTES = 16 * 1024
MAX_BODY_BYTES = 1024 * 1024
MAX_CHUNK_LINE = 1024  # a size line with its extensions; real servers send a few bytes


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
        self._chunked: _ChunkedBody | None = None

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
            if len(parts) < 2 or parts[0] not in ("HTTP/1.0", "HTTP/1.1") or not _is_status_code(parts[1]):
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
            if self._chunked is None:
                self._chunked = _ChunkedBody()
            body = self._chunked.feed(self._buf)
        elif "content-length" in headers:
            text = headers["content-length"]
            if not (text.isascii() and text.isdigit()) or len(text) > 16 or int(text) > MAX_BODY_BYTES:
                raise ProtocolError(f"bad Content-Length {text!r}")
            body = bytes(self._buf[: int(text)]) if len(self._buf) >= int(text) else None
        elif status in (204, 304):
            body = b""
        else:
            body = bytes(self._buf) if at_eof else None
        if len(self._buf) > MAX_BODY_BYTES + MAX_HEAD_BYTES:
            raise ProtocolError(f"HTTP body longer than {MAX_BODY_BYTES} bytes")
        return None if body is None else HttpResponse(status, reason, headers, body)


def _is_status_code(text: str) -> bool:
    return len(text) == 3 and text.isascii() and text.isdigit()


_HEX_DIGITS = frozenset(b"0123456789abcdefABCDEF")


class _ChunkedBody:
    """Incremental chunked-transfer decoder: consumes what it has decoded, so each byte is looked at once.

    Strict (RFC 9112 §7.1): a size is 1..16 hex digits and nothing else (no sign, no `0x`, no spaces
    except before an extension); every chunk ends with CRLF; the body, a size line and the trailers are
    bounded. A violation raises ProtocolError; nothing here can loop without consuming bytes.
    """

    def __init__(self) -> None:
        self.body = bytearray()
        self._chunk_left: int | None = None  # bytes of the current chunk still to come; None: a size line is next
        self._in_trailers = False
        self._trailer_bytes = 0

    def feed(self, buf: bytearray) -> bytes | None:
        """Decode from the front of `buf` (consuming it); the body once the last chunk and trailers are in."""
        while True:
            if self._in_trailers:
                eol = buf.find(b"\r\n")
                if eol < 0:
                    self._count_trailer(len(buf))
                    return None
                self._count_trailer(eol + 2)
                line = bytes(buf[:eol])
                del buf[: eol + 2]
                if not line:
                    return bytes(self.body)
                continue
            if self._chunk_left is None:
                eol = buf.find(b"\r\n")
                if eol < 0:
                    if len(buf) > MAX_CHUNK_LINE:
                        raise ProtocolError(f"chunk size line longer than {MAX_CHUNK_LINE} bytes")
                    return None
                if eol > MAX_CHUNK_LINE:
                    raise ProtocolError(f"chunk size line longer than {MAX_CHUNK_LINE} bytes")
                size = _chunk_size(bytes(buf[:eol]))
                del buf[: eol + 2]
                if size == 0:
                    self._in_trailers = True
                    continue
                if len(self.body) + size > MAX_BODY_BYTES:
                    raise ProtocolError(f"chunked HTTP body longer than {MAX_BODY_BYTES} bytes")
                self._chunk_left = size
            if len(buf) < self._chunk_left + 2:
                return None
            if buf[self._chunk_left : self._chunk_left + 2] != b"\r\n":
                raise ProtocolError("chunk data not followed by CRLF (a wrong chunk size?)")
            self.body += buf[: self._chunk_left]
            del buf[: self._chunk_left + 2]
            self._chunk_left = None

    def _count_trailer(self, n: int) -> None:
        self._trailer_bytes += n
        if self._trailer_bytes > MAX_HEAD_BYTES:
            raise ProtocolError(f"HTTP chunked trailer longer than {MAX_HEAD_BYTES} bytes")


def _chunk_size(line: bytes) -> int:
    """The size in a chunk-size line: 1..16 hex digits, optionally then `;extension`."""
    text, sep, _ = line.partition(b";")
    if sep:
        text = text.rstrip(b" \t")  # BWS before an extension
    if not text or len(text) > 16 or not all(byte in _HEX_DIGITS for byte in text):
        raise ProtocolError(f"bad chunk size {text[:20]!r}: expected 1 to 16 hex digits")
    return int(text, 16)
