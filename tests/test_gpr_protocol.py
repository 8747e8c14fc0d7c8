"""Bytes-in/bytes-out tests of the SPIDAR SDK-mode protocol: trace framing with resync, HTTP, the JSON API.

Frames are built here with `struct` directly (not with the module's encoder), so the parser is checked
against an independent writer of the documented layout `<LLLLHH` + float32 samples.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gprbot.config import GprDeviceConfig
from gprbot.drivers.gpr.protocol import (
    MAX_ABS_SAMPLE_MV,
    AcquisitionSetup,
    DeviceRejectedError,
    DuplicateTrace,
    HttpResponse,
    HttpResponseParser,
    Resync,
    TraceCounter,
    TraceEvent,
    TraceFrame,
    TraceGap,
    TraceStreamParser,
    api_form,
    build_request,
    encode_frame,
    first_break_ns,
    parse_api_reply,
    parse_data_port,
    parse_setup,
    parse_window_reference_ps,
    setup_from_config,
    setup_payload,
)
from gprbot.errors import ProtocolError

PPT = 6
STACKS = 4
TV_SEC = 1_700_000_000


def samples_of(number: int, ppt: int = PPT) -> np.ndarray:
    """Distinct, exactly representable samples per trace number (mV)."""
    return (np.arange(ppt, dtype=np.float32) - 2.5) * np.float32(0.5 + number)


def frame(number: int, samples: np.ndarray | None = None, *, tv_nsec: int = 0, status: int = 0,
          stacks: int = STACKS, header_size: int = 20, extra: bytes = b"") -> bytes:
    """A frame written independently of the module: header, optional extra header bytes, samples."""
    data = samples_of(number) if samples is None else samples
    head = struct.pack("<IIIIHH", TV_SEC + number, tv_nsec, number, status, stacks, header_size)
    return head + extra + struct.pack(f"<{len(data)}f", *data.tolist())


def stream_of(numbers: list[int]) -> bytes:
    return b"".join(frame(n, tv_nsec=1000 * n) for n in numbers)


def run(parser: TraceStreamParser, *chunks: bytes) -> list[object]:
    events: list[object] = []
    for chunk in chunks:
        events += parser.feed(chunk)
    return events + list(parser.close())


def traces(events: Sequence[object]) -> list[TraceFrame]:
    return [e for e in events if isinstance(e, TraceFrame)]


def as_tuples(events: Sequence[object]) -> list[tuple[object, ...]]:
    """Events as comparable tuples (arrays as bytes)."""
    out: list[tuple[object, ...]] = []
    for e in events:
        if isinstance(e, TraceFrame):
            out.append((e.tv_sec, e.tv_nsec, e.number, e.status, e.stacks, e.header_size, e.sequence,
                        e.samples.tobytes()))
        else:
            out.append((repr(e),))
    return out


# ---- framing ------------------------------------------------------------------------------------


def test_hand_built_frame_parses_to_exact_values() -> None:
    samples = np.array([1.5, -2.25, 0.0, 1000.0, -0.125, 3.0], dtype=np.float32)
    data = struct.pack("<IIIIHH", 1_700_000_123, 456_789_000, 42, 7, 16, 20) + struct.pack("<6f", *samples)
    assert len(data) == 20 + 4 * PPT
    [trace] = traces(run(TraceStreamParser(PPT), data))
    assert (trace.tv_sec, trace.tv_nsec, trace.number, trace.status, trace.stacks, trace.header_size) == (
        1_700_000_123, 456_789_000, 42, 7, 16, 20)
    assert trace.samples.dtype == np.float32
    assert trace.samples.tolist() == [1.5, -2.25, 0.0, 1000.0, -0.125, 3.0]
    assert trace.device_time_s == pytest.approx(1_700_000_123.456789)


def test_module_encoder_matches_the_documented_layout() -> None:
    assert encode_frame(9, samples_of(9), TV_SEC + 9, 9000, STACKS) == frame(9, tv_nsec=9000)


def test_a_frame_is_delivered_once_the_next_header_confirms_it() -> None:
    parser = TraceStreamParser(PPT)
    first, second = frame(1), frame(2)
    assert parser.feed(first) == []
    assert parser.feed(second[:19]) == []  # one byte short of the next header
    assert [t.number for t in traces(parser.feed(second[19:]))] == [1]
    assert [t.number for t in traces(parser.close())] == [2]


def test_split_at_every_byte_boundary_gives_the_same_result() -> None:
    data = stream_of([1, 2, 3, 4])
    reference = as_tuples(run(TraceStreamParser(PPT), data))
    assert [t[2] for t in reference] == [1, 2, 3, 4]
    for cut in range(len(data) + 1):
        assert as_tuples(run(TraceStreamParser(PPT), data[:cut], data[cut:])) == reference, cut
    assert as_tuples(run(TraceStreamParser(PPT), *(data[i : i + 1] for i in range(len(data))))) == reference


def test_larger_header_size_skips_unknown_fields() -> None:
    data = frame(1, header_size=28, extra=b"\xaa" * 8) + frame(2, header_size=28, extra=b"\xbb" * 8)
    got = traces(run(TraceStreamParser(PPT), data))
    assert [(t.number, t.header_size) for t in got] == [(1, 28), (2, 28)]
    assert np.array_equal(got[0].samples, samples_of(1)) and np.array_equal(got[1].samples, samples_of(2))


def test_a_header_size_corrupted_to_a_valid_larger_one_does_not_pass_the_next_frames_samples_off_as_its_own() -> None:
    """Byte 18 of trace 1 flipped 20 -> 64: its "extra header" swallows its samples and trace 2's header, so it
    would take trace 2's samples, and trace 3's header would confirm it (found by the property test below)."""
    data = bytearray(stream_of([1, 2, 3, 4]))
    data[18] ^= 84
    parser = TraceStreamParser(PPT, stacks=STACKS)
    events = run(parser, bytes(data))
    got = traces(events)
    assert [t.number for t in got] == [2, 3, 4]
    assert all(np.array_equal(t.samples, samples_of(t.number)) for t in got)
    assert any(isinstance(e, Resync) and "header size 64" in e.reason for e in events)


def test_gaps_are_drops_and_duplicates_are_discarded() -> None:
    parser = TraceStreamParser(PPT)
    events = run(parser, stream_of([1, 2, 5, 6]))
    assert [t.number for t in traces(events)] == [1, 2, 5, 6]
    assert TraceGap(2, 5) in events and TraceGap(2, 5).missing == 2
    assert parser.drops == 2 and parser.resyncs == 0
    counter = TraceCounter()
    again: list[TraceEvent] = []
    assert counter.admit(3, again) == 3 and counter.admit(3, again) is None and counter.duplicates == 1
    assert again == [DuplicateTrace(3)]


def test_counter_keeps_numbers_increasing_across_a_device_restart() -> None:
    counter = TraceCounter()
    first = traces(run(TraceStreamParser(PPT, counter=counter), stream_of([1, 2, 3])))
    counter.new_epoch()  # our setup: the NIC counts from 1 again
    second = run(TraceStreamParser(PPT, counter=counter), stream_of([2, 3]))
    assert [t.sequence for t in first] == [1, 2, 3]
    assert [(t.number, t.sequence) for t in traces(second)] == [(2, 5), (3, 6)]
    assert TraceGap(0, 2) in second and counter.drops == 1  # trace 1 of the new epoch never came


# ---- resync -------------------------------------------------------------------------------------

GOOD = [frame(n, tv_nsec=1000 * n) for n in range(1, 6)]


HEADER_FAULTS = {
    "header_size_22": frame(3, header_size=22),
    "header_size_0": frame(3, header_size=0),
    "stacks_3": frame(3, stacks=3),
    "stacks_8": frame(3, stacks=8),  # plausible alone, but not the stacks we set up
    "status_high_bits": frame(3, status=0x10000),
    "tv_nsec_1e9": frame(3, tv_nsec=1_000_000_000),
}
SAMPLE_FAULTS = {
    "nan": frame(3, samples=np.array([0, 1, np.nan, 2, 3, 4], dtype=np.float32)),
    "inf": frame(3, samples=np.array([0, 1, np.inf, 2, 3, 4], dtype=np.float32)),
    "200_volts": frame(3, samples=np.array([0, 1, 2e5, 2, 3, 4], dtype=np.float32)),
}


@pytest.mark.parametrize("fault", [*HEADER_FAULTS, *SAMPLE_FAULTS])
def test_a_corrupt_frame_is_skipped_and_later_traces_are_exact(fault: str) -> None:
    """A bad header also costs the frame before it (nothing confirms that frame's end); bad samples
    cost only their own frame."""
    header_fault = fault in HEADER_FAULTS
    corrupt = HEADER_FAULTS[fault] if header_fault else SAMPLE_FAULTS[fault]
    parser = TraceStreamParser(PPT, stacks=STACKS)
    events = run(parser, GOOD[0] + GOOD[1] + corrupt + GOOD[3] + GOOD[4])
    got = traces(events)
    assert [t.number for t in got] == ([1, 4, 5] if header_fault else [1, 2, 4, 5])
    for t in got:
        assert np.array_equal(t.samples, samples_of(t.number))
    [resync] = [e for e in events if isinstance(e, Resync)]
    lost = len(GOOD[1]) + len(corrupt) if header_fault else len(corrupt)
    assert resync.offset == 2 * len(GOOD[0]) - (len(GOOD[1]) if header_fault else 0)
    assert parser.resyncs == 1 and parser.bytes_skipped == lost and parser.drops == (2 if header_fault else 1)


def test_garbage_before_the_first_frame_is_skipped_exactly() -> None:
    parser = TraceStreamParser(PPT)
    got = traces(run(parser, b"\xff" * 13 + GOOD[0] + GOOD[1]))
    assert [t.number for t in got] == [1, 2] and parser.bytes_skipped == 13 and parser.resyncs == 1


def test_bytes_inserted_inside_a_frame_are_caught_although_the_frame_looks_plausible() -> None:
    """Four noise bytes inside frame 3: its first 44 bytes still form a plausible frame of shifted but
    finite samples; only the misaligned header after it gives it away."""
    bad = GOOD[2][:28] + b"\x01\x02\x03\x04" + GOOD[2][28:]
    shifted = np.frombuffer(bad[20 : 20 + 4 * PPT], dtype="<f4")
    assert np.all(np.abs(shifted) <= MAX_ABS_SAMPLE_MV) and not np.array_equal(shifted, samples_of(3))
    parser = TraceStreamParser(PPT)
    got = traces(run(parser, GOOD[0] + GOOD[1] + bad + GOOD[3] + GOOD[4]))
    assert [t.number for t in got] == [1, 2, 4, 5]
    assert all(np.array_equal(t.samples, samples_of(t.number)) for t in got)
    assert parser.resyncs == 1 and parser.bytes_skipped == len(bad)


def test_noise_between_frames_costs_the_frame_before_it() -> None:
    parser = TraceStreamParser(PPT)
    got = traces(run(parser, GOOD[0] + GOOD[1] + b"\x00\x11" * 7 + GOOD[2] + GOOD[3]))
    assert [t.number for t in got] == [1, 3, 4]  # 2 cannot be told from a frame with 14 bytes inserted
    assert parser.resyncs == 1 and parser.bytes_skipped == len(GOOD[1]) + 14 and parser.drops == 1


@pytest.mark.parametrize("claimed", [2, 4, 9])
def test_a_corrupted_trace_number_never_yields_a_wrong_trace(claimed: int) -> None:
    """Frame 3's body under another number: whichever neighbour it contradicts is dropped with it."""
    renumbered = frame(claimed, samples_of(3), tv_nsec=3000)
    data = GOOD[0] + GOOD[1] + renumbered + GOOD[3] + GOOD[4] + frame(6, tv_nsec=6000)
    got = traces(run(TraceStreamParser(PPT), data))
    assert all(np.array_equal(t.samples, samples_of(t.number)) for t in got)
    assert {1, 5, 6} <= {t.number for t in got} and 3 not in {t.number for t in got}


def test_in_place_payload_corruption_is_indistinguishable() -> None:
    """The documented limit: a flipped mantissa bit leaves a plausible frame, delivered as data."""
    bad = bytearray(GOOD[2])
    bad[20] ^= 0x01
    got = traces(run(TraceStreamParser(PPT), GOOD[0] + GOOD[1] + bytes(bad) + GOOD[3]))
    assert [t.number for t in got] == [1, 2, 3, 4]
    assert not np.array_equal(got[2].samples, samples_of(3))


def test_a_torn_tail_at_close_is_counted_not_delivered() -> None:
    parser = TraceStreamParser(PPT)
    got = traces(run(parser, GOOD[0] + GOOD[1] + GOOD[2][:30]))
    assert [t.number for t in got] == [1, 2] and parser.bytes_skipped == 30 and parser.resyncs == 0


# ---- properties ---------------------------------------------------------------------------------

HYPO = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
CLEAN = b"".join(frame(n, tv_nsec=7919 * n) for n in range(1, 13))
FRAME_LEN = len(GOOD[0])


def check_invariants(parser: TraceStreamParser, got: list[TraceFrame], fed: int) -> None:
    numbers = [t.number for t in got]
    assert numbers == sorted(set(numbers))
    for t in got:
        assert t.samples.shape == (PPT,) and t.samples.dtype == np.float32
        assert np.all(np.abs(t.samples) <= MAX_ABS_SAMPLE_MV)
        assert 20 <= t.header_size <= 64 and t.tv_nsec < 1_000_000_000 and t.number >= 1
    assert 0 <= parser.bytes_skipped <= fed


@HYPO
@given(st.binary(max_size=600), st.integers(1, 50))
def test_random_bytes_never_crash_and_yield_only_plausible_traces(data: bytes, chunk: int) -> None:
    parser = TraceStreamParser(PPT)
    got = traces(run(parser, *(data[i : i + chunk] for i in range(0, len(data), chunk))))
    check_invariants(parser, got, len(data))


@HYPO
@given(st.lists(st.tuples(st.integers(0, len(CLEAN)), st.binary(min_size=1, max_size=40)), max_size=4),
       st.integers(1, 97))
def test_inserted_noise_never_yields_a_wrong_trace(inserts: list[tuple[int, bytes]], chunk: int) -> None:
    """Noise bursts inserted anywhere: every delivered trace is an original one (number and samples;
    noise inside the timestamp fields can shift them plausibly, which nothing can check), and the frames
    away from the bursts are delivered."""
    data = bytearray(CLEAN)
    for position, noise in sorted(inserts, reverse=True):
        data[position:position] = noise
    parser = TraceStreamParser(PPT, stacks=STACKS)
    got = traces(run(parser, *(bytes(data[i : i + chunk]) for i in range(0, len(data), chunk))))
    check_invariants(parser, got, len(data))
    for t in got:
        assert np.array_equal(t.samples, samples_of(t.number))
    hit = {min(p // FRAME_LEN + 1, 12) for p, _ in inserts} | {max(p // FRAME_LEN, 1) for p, _ in inserts}
    # A burst costs its frame and at most one on each side; the last frame, with no successor to confirm
    # it, is delivered only if the frame before it was.
    expected = {n for n in range(1, 13) if not hit & {n - 1, n, n + 1} and (n < 12 or 10 not in hit)}
    assert expected <= {t.number for t in got}


@HYPO
@given(st.integers(0, len(CLEAN) - 1), st.integers(1, 255))
def test_one_corrupted_header_byte_never_yields_a_wrong_trace(position: int, xor: int) -> None:
    data = bytearray(CLEAN)
    data[position] ^= xor
    parser = TraceStreamParser(PPT, stacks=STACKS)
    got = traces(run(parser, bytes(data)))
    check_invariants(parser, got, len(data))
    victim = position // FRAME_LEN + 1
    in_header = position % FRAME_LEN < 20
    for t in got:
        if t.number != victim or in_header:
            assert np.array_equal(t.samples, samples_of(t.number))
    # The last frame has no successor to confirm it: it also needs its predecessor delivered.
    assert {n for n in range(1, 13) if abs(n - victim) > 1 and (n < 12 or victim < 10)} <= {t.number for t in got}


@HYPO
@given(st.lists(st.tuples(st.integers(0, len(CLEAN) - 1), st.integers(0, 255)), max_size=12),
       st.lists(st.tuples(st.integers(0, len(CLEAN)), st.integers(1, 30)), max_size=3))
def test_mutated_streams_keep_numbers_increasing_and_lengths_exact(
    changes: list[tuple[int, int]], deletions: list[tuple[int, int]]
) -> None:
    """Substitutions and deletions anywhere: corrupted payloads that stay plausible cannot be told
    from data, so what is guaranteed is shape: no crash, PPT finite samples, increasing numbers."""
    data = bytearray(CLEAN)
    for position, value in changes:
        data[position] = value
    for position, length in sorted(deletions, reverse=True):
        del data[position : position + length]
    parser = TraceStreamParser(PPT)
    check_invariants(parser, traces(run(parser, bytes(data))), len(data))


# ---- HTTP ---------------------------------------------------------------------------------------


def test_put_request_bytes_are_a_form_with_the_json_in_data() -> None:
    request = build_request("PUT", "192.168.20.221", 8080, "/api/nic/power", api_form({"state": 2}))
    head, body = request.split(b"\r\n\r\n")
    assert head.split(b"\r\n")[0] == b"PUT /api/nic/power HTTP/1.1"
    assert b"Host: 192.168.20.221:8080" in head and b"Connection: close" in head
    assert b"Content-Type: application/x-www-form-urlencoded" in head
    assert body == b"data=%7B%22state%22%3A+2%7D" and f"Content-Length: {len(body)}".encode() in head
    get = build_request("GET", "h", 1, "/api")
    assert get.endswith(b"\r\n\r\n") and b"Content-Length" not in get


def feed_all(raw: bytes, step: int) -> HttpResponse | None:
    parser = HttpResponseParser()
    result = None
    for i in range(0, len(raw), step):
        result = parser.feed(raw[i : i + step]) or result
    return result


@pytest.mark.parametrize(
    "raw",
    [
        b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: 11\r\n\r\n{\"a\": [1]}\n",
        b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n4;x=y\r\n{\"a\"\r\n7\r\n: [1]}\n\r\n0\r\n\r\n",
        b"HTTP/1.1 100 Continue\r\n\r\nHTTP/1.0 200 OK\r\ncontent-length: 11\r\n\r\n{\"a\": [1]}\n",
    ],
)
def test_good_responses_parse_at_any_split(raw: bytes) -> None:
    for step in (1, 2, 7, len(raw)):
        response = feed_all(raw, step)
        assert response is not None and response.status == 200 and response.body == b'{"a": [1]}\n', step


def test_body_until_close_and_truncation() -> None:
    parser = HttpResponseParser()
    assert parser.feed(b"HTTP/1.0 200 OK\r\n\r\n{}") is None
    assert parser.close().body == b"{}"
    cut = HttpResponseParser()
    assert cut.feed(b"HTTP/1.1 200 OK\r\nContent-Length: 10\r\n\r\n{}") is None
    with pytest.raises(ProtocolError, match="before the end of the HTTP body"):
        cut.close()
    with pytest.raises(ProtocolError, match="before a complete HTTP head"):
        HttpResponseParser().close()


@pytest.mark.parametrize(
    ("raw", "match"),
    [
        (b"SSH-2.0-OpenSSH_9.6\r\n", "not an HTTP response"),
        (b"HTTP/2 200\r\n\r\n", "malformed HTTP status line"),
        (b"HTTP/1.1 OK 200\r\n\r\n", "malformed HTTP status line"),
        (b"HTTP/1.1 200 OK\r\nno colon here\r\n\r\n", "malformed HTTP header"),
        (b"HTTP/1.1 200 OK\r\nContent-Length: -3\r\n\r\n", "bad Content-Length"),
        (b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\nzz\r\n", "bad chunk size"),
        (b"HTTP/1.1 200 OK\r\nX: " + b"a" * 20000, "HTTP head longer"),
    ],
)
def test_bad_responses_raise_protocol_errors(raw: bytes, match: str) -> None:
    with pytest.raises(ProtocolError, match=match):
        HttpResponseParser().feed(raw)


# ---- the JSON API -------------------------------------------------------------------------------


def reply(doc: object, status: int = 200) -> HttpResponse:
    return HttpResponse(status, "OK", {}, json.dumps(doc).encode())


def test_api_envelope_success_warning_and_errors() -> None:
    ok = parse_api_reply(reply({"status": {"status_code": 0, "message": "fine", "type": "SUCCESS"},
                                "data": {"state": 2}, "success": True}), "nic/power")
    assert ok.data == {"state": 2} and ok.status_code == 0
    warned = parse_api_reply(reply({"status": {"status_code": 913, "type": "WARNING"}, "data": {}}), "nic/setup")
    assert warned.status_code == 913
    assert parse_api_reply(reply({"data": {"state": 1}}), "nic/power").data == {"state": 1}  # docs' bare form
    with pytest.raises(DeviceRejectedError, match="status 4001") as err:
        parse_api_reply(reply({"status": {"status_code": 4001, "message": "GPR Not Powered", "type": "ERROR"}}),
                        "nic/setup")
    assert err.value.status_code == 4001 and err.value.http_status == 200
    with pytest.raises(DeviceRejectedError) as err:
        parse_api_reply(reply({"status": {"status_code": 8, "message": "Value out of range"}}, 400), "nic/setup")
    assert err.value.http_status == 400
    with pytest.raises(DeviceRejectedError):
        parse_api_reply(reply({"success": False, "data": None}), "nic/setup")
    with pytest.raises(ProtocolError, match="not JSON"):
        parse_api_reply(HttpResponse(200, "OK", {}, b"<html>router login</html>"), "api")
    with pytest.raises(ProtocolError, match="not an object"):
        parse_api_reply(reply([1, 2]), "api")


def test_setup_from_config_and_back_from_the_docs_sample() -> None:
    cfg = GprDeviceConfig(points_per_trace=200, time_sampling_interval_ps=100.0, stacks=4,
                          window_shift_ns=-1.0, trigger_period_s=0.01)
    setup = setup_from_config(cfg, reference_ps=-45000.0)
    assert setup == AcquisitionSetup(200, 100.0, 4, -46000, 0.01, "Free")
    assert first_break_ns(setup, -45000.0) == pytest.approx(1.0)
    payload = setup_payload(setup)
    assert payload["gpr0"]["parameters"]["time_sampling_interval_ps"] == 100
    assert isinstance(payload["gpr0"]["parameters"]["time_sampling_interval_ps"], int)
    assert payload["timer"] == {"parameters": {"period_s": 0.01}}
    assert setup_from_config(cfg, None).window_time_shift_ps == -56000  # vendor default reference
    docs_sample = {"timer": {"parameters": {"period_s": 0.1}}, "gpr": {"parameters": {
        "time_sampling_interval_ps": 100, "frequency_MHz": 1000, "point_stacks": 32, "trigger_mode": "Free",
        "window_time_shift_ps": -37000, "points_per_trace": 200}}}
    assert parse_setup(docs_sample) == AcquisitionSetup(200, 100.0, 32, -37000.0, 0.1, "Free")
    assert parse_setup(payload) == setup
    with pytest.raises(ProtocolError):
        parse_setup({"gpr0": {"parameters": {"points_per_trace": 1}}, "timer": {"parameters": {}}})


def test_small_api_fields() -> None:
    assert parse_data_port({"data_socket": {"port": 60039}}) == 60039
    with pytest.raises(ProtocolError):
        parse_data_port({"data_socket": {"port": 0}})
    assert parse_window_reference_ps({"gpr": {"window_time_shift_reference_ps": -45000}}) == -45000.0
    assert parse_window_reference_ps({"gpr": {"window_time_shift_reference_ps": None}}) is None


def test_every_single_corrupted_header_byte_leaves_the_other_traces_whole() -> None:
    """Exhaustive over the twelve headers' bytes and every nonzero XOR (61 200 streams, ~8 s): no delivered
    trace carries another's samples, and every trace not beside the corrupted one arrives (before the layout
    check, 11 of the 134 640 single-byte corruptions of the whole stream gave a trace the next one's samples)."""
    for position in (p for p in range(len(CLEAN)) if p % FRAME_LEN < 20):
        victim = position // FRAME_LEN + 1
        expected = {n for n in range(1, 13) if abs(n - victim) > 1 and (n < 12 or victim < 10)}
        for xor in range(1, 256):
            data = bytearray(CLEAN)
            data[position] ^= xor
            got = traces(run(TraceStreamParser(PPT, stacks=STACKS), bytes(data)))
            assert all(np.array_equal(t.samples, samples_of(t.number)) for t in got), (position, xor)
            assert expected <= {t.number for t in got}, (position, xor)
