"""Issue 15 #7: resynchronising on adversarial garbage costs work linear in the bytes received."""

from __future__ import annotations

import types

import numpy as np
import pytest

from gprbot.drivers.gpr import trace_stream
from gprbot.drivers.gpr.trace_stream import HEADER, TraceFrame, TraceStreamParser, encode_frame

POINTS = 512


def adversarial_garbage(size: int) -> bytes:
    """Back-to-back plausible headers whose samples are NaN: every one is a candidate that then fails."""
    unit = HEADER.pack(1_700_000_000, 0, 1, 0, 1, 20) + b"\xff\xff\xff\xff"
    return (unit * (size // len(unit) + 1))[:size]


class _CountingNumpy(types.SimpleNamespace):
    """numpy with frombuffer counting the bytes it views: the parser's work, machine-independent."""

    def __init__(self) -> None:
        super().__init__(viewed=0)

    def frombuffer(self, buffer: object, *args: object, **kwargs: object) -> np.ndarray:
        array = np.frombuffer(buffer, *args, **kwargs)  # type: ignore[call-overload]
        self.viewed += array.nbytes
        return array

    def __getattr__(self, name: str) -> object:
        return getattr(np, name)


def bytes_viewed(monkeypatch: pytest.MonkeyPatch, data: bytes, chunk: int) -> int:
    counting = _CountingNumpy()
    monkeypatch.setattr(trace_stream, "np", counting)
    parser = TraceStreamParser(POINTS, stacks=1)
    for i in range(0, len(data), chunk):
        parser.feed(data[i : i + chunk])
    parser.close()
    monkeypatch.setattr(trace_stream, "np", np)
    return counting.viewed


@pytest.mark.parametrize("chunk", [64 * 1024, 4096])
def test_resync_work_grows_linearly_with_adversarial_garbage(monkeypatch: pytest.MonkeyPatch, chunk: int) -> None:
    small = bytes_viewed(monkeypatch, adversarial_garbage(93 * 1024), chunk)
    large = bytes_viewed(monkeypatch, adversarial_garbage(4 * 93 * 1024), chunk)
    # quadratic work would make the ratio ~16 and the per-byte work grow with the read size
    assert large / small < 5.0
    assert small / (93 * 1024) < 64


def test_good_traces_after_adversarial_garbage_are_still_delivered_exactly() -> None:
    rng = np.random.default_rng(1)
    samples = [rng.normal(0, 20, POINTS).astype(np.float32) for _ in range(4)]
    frames = b"".join(encode_frame(n + 1, s, stacks=1) for n, s in enumerate(samples))
    parser = TraceStreamParser(POINTS, stacks=1)
    events = []
    data = adversarial_garbage(50_000) + frames
    for i in range(0, len(data), 7000):
        events += parser.feed(data[i : i + 7000])
    events += parser.close()
    got = [e for e in events if isinstance(e, TraceFrame)]
    assert [e.number for e in got] == [1, 2, 3, 4]
    for frame, expected in zip(got, samples, strict=True):
        np.testing.assert_array_equal(frame.samples, expected)
    assert parser.resyncs == 1
