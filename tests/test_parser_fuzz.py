"""Every boundary parser takes arbitrary bytes without crashing (short hypothesis runs; the long run is
`python -m benchmarks.fuzz_parsers`)."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.fuzz_targets import SAMPLE_LOG, TARGETS

SEEDS = [b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n5\r\nhello\r\n0\r\n\r\n",
         b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\n\r\n{}", b"auth 'x\"y\\z'\nestop\n",
         b"ok pull 3 " + b"a" * 64 + b"\n",
         b"gpr: {samples: 512}\nshell: {port: 7878}\n", SAMPLE_LOG[:64]]


def _mutations() -> st.SearchStrategy[bytes]:
    seeded = st.tuples(st.sampled_from(SEEDS), st.binary(max_size=24), st.integers(0, 200)).map(
        lambda t: t[0][: t[2]] + t[1] + t[0][t[2]:])
    return st.one_of(st.binary(max_size=600), seeded)


@pytest.mark.parametrize("name", sorted(TARGETS))
def test_a_parser_survives_arbitrary_bytes(name: str) -> None:
    target = TARGETS[name]

    @settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow], database=None)
    @given(_mutations())
    def run(data: bytes) -> None:
        target(data)

    run()
