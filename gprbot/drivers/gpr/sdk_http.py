"""Sans-IO HTTP/1.1: the minimal client side the NIC-500's control API needs (no I/O, no clock)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from urllib.parse import urlencode

from gprbot.errors import ProtocolError

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
