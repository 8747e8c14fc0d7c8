"""Issue 15 #2: the NIC's HTTP replies are parsed with strict, bounded chunk framing (no loop can hang)."""

from __future__ import annotations

import pytest

from gprbot.drivers.gpr.sdk_http import MAX_BODY_BYTES, HttpResponseParser
from gprbot.errors import ProtocolError

HEAD = b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n"


@pytest.mark.timeout(5)
@pytest.mark.parametrize("size_line", [b"-6", b"+6", b" 6", b"6 ", b"0x6", b"6_0", b"", b"g", "٣".encode(),
                                       b"1" * 17, b"6;" + b"x" * 5000])
def test_a_chunk_size_that_is_not_plain_hex_is_refused_at_once(size_line: bytes) -> None:
    with pytest.raises(ProtocolError, match="chunk"):
        HttpResponseParser().feed(HEAD + size_line + b"\r\n")


@pytest.mark.timeout(5)
def test_a_chunk_larger_than_the_body_limit_is_refused_before_it_arrives() -> None:
    with pytest.raises(ProtocolError, match="chunk"):
        HttpResponseParser().feed(HEAD + f"{MAX_BODY_BYTES + 1:x}".encode() + b"\r\n")


@pytest.mark.timeout(5)
def test_chunks_adding_up_beyond_the_body_limit_are_refused() -> None:
    parser = HttpResponseParser()
    parser.feed(HEAD)
    chunk = f"{64 * 1024:x}\r\n".encode() + b"a" * 64 * 1024 + b"\r\n"
    with pytest.raises(ProtocolError, match="longer than"):
        for _ in range(MAX_BODY_BYTES // (64 * 1024) + 2):
            parser.feed(chunk)


@pytest.mark.timeout(5)
def test_a_chunk_not_followed_by_crlf_is_refused() -> None:
    with pytest.raises(ProtocolError, match="chunk"):
        HttpResponseParser().feed(HEAD + b"3\r\nabcXY0\r\n\r\n")


@pytest.mark.timeout(5)
def test_endless_trailers_are_bounded() -> None:
    parser = HttpResponseParser()
    parser.feed(HEAD + b"0\r\n")
    with pytest.raises(ProtocolError, match="trailer"):
        for _ in range(2000):
            parser.feed(b"X-Trailer: " + b"y" * 20 + b"\r\n")


@pytest.mark.timeout(5)
def test_chunk_extensions_and_trailers_still_parse() -> None:
    raw = HEAD + b"3;name=value\r\nabc\r\n2\r\nde\r\n0\r\nX-Checksum: 1\r\n\r\n"
    response = HttpResponseParser().feed(raw)
    assert response is not None and response.body == b"abcde"


@pytest.mark.timeout(5)
def test_a_content_length_with_a_sign_or_spaces_is_refused() -> None:
    for text in (b"-1", b"+5", "٣".encode()):
        with pytest.raises(ProtocolError, match="Content-Length"):
            HttpResponseParser().feed(b"HTTP/1.1 200 OK\r\nContent-Length: " + text + b"\r\n\r\n")


def test_a_status_code_in_non_ascii_digits_is_refused() -> None:
    # latin-1 b"\xb2" is "²", which str.isdigit() accepts but int() refuses (a ValueError escaped before)
    with pytest.raises(ProtocolError, match="status line"):
        HttpResponseParser().feed(b"HTTP/1.1 \xb2\xb2\xb2 OK\r\n\r\n")
