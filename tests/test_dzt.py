"""DZT read/write, checked against readgssi (an independent reader) and the real SIR-3000 file."""

from __future__ import annotations

import contextlib
import functools
import io
import json
import os
import struct
import tempfile
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from readgssi.constants import UNIT
from readgssi.dzt import readdzt

from gprbot.errors import DataFormatError
from gprbot.gpr.dzt import format_info, header_info, parse_dzt, read_dzt, write_dzt
from gprbot.gpr.traveltime import velocity_from_eps

INT_RANGES = {8: (0, 255), 16: (0, 65535), 32: (-(2**31), 2**31 - 1)}
STORED = {8: np.uint8, 16: np.uint16, 32: np.int32}


def readgssi_view(path: Path) -> tuple[dict[str, Any], list[NDArray[Any]]]:
    """readgssi's header dict and its int32 (samples, traces) array per channel, printing silenced."""
    # readgssi prints progress to stdout. zero=[0]*4 stops it cutting rh_zero samples off each trace.
    with contextlib.redirect_stdout(io.StringIO()):
        header, arrays, _gps = readdzt(str(path), zero=[0, 0, 0, 0])
    return header, [arrays[k] for k in range(header["rh_nchan"])]


def assert_header_matches_readgssi(ours: Any, theirs: dict[str, Any]) -> None:
    """Every DztHeader field equals readgssi's reading of the same bytes."""
    assert ours.channels == theirs["rh_nchan"]
    assert ours.samples == theirs["rh_nsamp"]
    assert ours.bits == theirs["rh_bits"]
    assert ours.traces == theirs["shape"][1]
    assert ours.range_ns == theirs["rhf_range"]
    assert ours.position_ns == theirs["rhf_position"]
    assert ours.traces_per_m == theirs["dzt_spm"]
    assert ours.traces_per_s == theirs["dzt_sps"]
    assert ours.eps_r == theirs["dzt_epsr"]
    assert ours.depth_m == theirs["dzt_depth"]
    assert ours.antenna == theirs["rh_ant"][0]
    assert ours.data_offset == theirs["data_offset"]
    # readgssi returns dates as UTC-aware, and 1980-01-01 (naive) for an unset date; ours are naive/None.
    for mine, key in ((ours.created, "rhb_cdt"), (ours.modified, "rhb_mdt")):
        expected = theirs[key].replace(tzinfo=None)
        assert mine == (None if expected == datetime(1980, 1, 1) else expected)
    code = theirs["rh_system"]
    assert ours.system == (None if code == 0 else UNIT[code].replace("SIR ", "SIR-"))


@functools.cache
def small_file_bytes() -> bytes:
    """A valid 2-channel, 16-bit file of 8 samples x 5 traces (for mutation tests)."""
    data = np.arange(2 * 8 * 5, dtype=np.uint16).reshape(2, 8, 5) * 97
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "small.dzt"
        write_dzt(path, data, range_ns=20.0, antenna="900MHz", created=datetime(2024, 5, 6, 7, 8, 10))
        return path.read_bytes()


# --- the real SIR-3000 file --------------------------------------------------------------------


def test_real_file_header_is_what_the_unit_recorded(real_dzt: Path) -> None:
    header = read_dzt(real_dzt).header
    assert (header.system, header.antenna) == ("SIR-3000", "400MHz")
    assert (header.channels, header.samples, header.traces, header.bits) == (1, 512, 1040, 16)
    assert (header.range_ns, header.traces_per_m, header.traces_per_s, header.eps_r) == (48.0, 50, 100, 6)
    assert header.created == datetime(2017, 3, 21, 0, 36, 46)
    assert header.modified == datetime(2017, 3, 21, 0, 38, 6)
    assert header.dt_ns == pytest.approx(48.0 / 512)
    # GSSI derives rhf_depth with c = 0.3 m/ns: 0.3 / sqrt(6) * 48 ns / 2.
    assert header.depth_m == pytest.approx(0.3 / np.sqrt(6.0) * 24.0, rel=1e-6)


def test_real_file_matches_readgssi(real_dzt: Path) -> None:
    ours = read_dzt(real_dzt)
    theirs, arrays = readgssi_view(real_dzt)
    assert_header_matches_readgssi(ours.header, theirs)
    assert ours.channels[0].dtype == np.uint16
    np.testing.assert_array_equal(ours.channels[0], arrays[0])


def test_real_file_marker_samples_and_as_float(real_dzt: Path) -> None:
    dzt = read_dzt(real_dzt)
    raw = dzt.channels[0]
    np.testing.assert_array_equal(raw[0], np.arange(1040))  # sample 0: the trace counter
    assert set(np.flatnonzero(raw[1])) == set(range(0, 1040, 100))  # sample 1: a user mark each 100
    signal = dzt.as_float()
    assert signal.shape == (1040, 512) and signal.dtype == np.float32
    assert not signal[:, :2].any()  # counter and marks neutralised
    np.testing.assert_array_equal(signal[:, 2:], raw[2:].T.astype(np.float32) - 32768.0)
    assert abs(float(signal.mean())) < 10.0  # zero-centred: the offset is 32768 of 65536 counts


# --- round trips read back by readgssi ----------------------------------------------------------


@pytest.mark.parametrize("bits", [8, 16, 32])
@pytest.mark.parametrize("n_channels", [1, 2, 3])
def test_round_trip_integer_samples_through_readgssi(tmp_path: Path, bits: int, n_channels: int) -> None:
    rng = np.random.default_rng(bits * 10 + n_channels)
    low, high = INT_RANGES[bits]
    data = [rng.integers(low, high, size=(64, 23), endpoint=True).astype(STORED[bits]) for _ in range(n_channels)]
    path = tmp_path / "line.dzt"
    created = datetime(2023, 11, 5, 14, 2, 31)
    write_dzt(
        path,
        data,
        range_ns=35.5,
        bits=bits,
        traces_per_m=100.0,
        traces_per_s=64.0,
        eps_r=9.0,
        antenna="62000-003",
        created=created,
        position_ns=-1.25,
    )
    ours = read_dzt(path)
    theirs, arrays = readgssi_view(path)
    assert_header_matches_readgssi(ours.header, theirs)
    header = ours.header
    assert (header.channels, header.samples, header.traces, header.bits) == (n_channels, 64, 23, bits)
    assert (header.range_ns, header.traces_per_m, header.traces_per_s, header.eps_r) == (35.5, 100, 64, 9)
    assert (header.position_ns, header.antenna, header.modified) == (-1.25, "62000-003", None)
    assert header.created == created.replace(second=30)  # DZT dates hold even seconds
    assert header.depth_m == pytest.approx(velocity_from_eps(9.0) * 35.5 / 2, rel=1e-6)
    assert theirs["antfreq"][0] == 2000  # readgssi knows the antenna model
    assert header.data_offset == 1024 * n_channels
    for k in range(n_channels):
        assert ours.channels[k].dtype == STORED[bits]
        np.testing.assert_array_equal(ours.channels[k], data[k])
        np.testing.assert_array_equal(arrays[k], data[k])


@pytest.mark.parametrize("bits", [8, 16, 32])
def test_float_input_is_scaled_to_full_scale_and_centred(tmp_path: Path, bits: int) -> None:
    t = np.linspace(0.0, 1.0, 50)
    wave = np.sin(2 * np.pi * 3 * t)[:, None] * np.array([1.0, -0.5, 0.25])  # (samples, 3 traces)
    second = 2.0 * wave  # the peak of all channels sets the one common scale
    path = tmp_path / "float.dzt"
    write_dzt(path, [wave, second], range_ns=10.0, bits=bits)
    dzt = read_dzt(path)
    full = 2 ** (bits - 1) - 1
    scale = full / np.abs(second).max()
    for k, original in enumerate((wave, second)):
        np.testing.assert_array_equal(dzt.as_float(k), np.rint(original.T * scale).astype(np.float32))
    assert dzt.as_float(1).max() == full
    _, arrays = readgssi_view(path)
    np.testing.assert_array_equal(arrays[0], dzt.channels[0])


def test_rh_data_block_count_rule_agrees_with_readgssi(tmp_path: Path) -> None:
    # rh_data < 1024 counts 1024-byte blocks: rh_data = 2 puts the data at byte 2048, after a second
    # (extended) header block; readgssi and the GSSI spec use this rule.
    data = np.arange(16 * 4, dtype=np.uint16).reshape(16, 4)
    path = tmp_path / "extended.dzt"
    write_dzt(path, data, range_ns=8.0)
    raw = bytearray(path.read_bytes())
    raw[2:4] = struct.pack("<h", 2)
    raw[1024:1024] = b"\xee" * 1024
    path.write_bytes(bytes(raw))
    ours = read_dzt(path)
    theirs, arrays = readgssi_view(path)
    assert ours.header.data_offset == theirs["data_offset"] == 2048
    np.testing.assert_array_equal(ours.channels[0], data)
    np.testing.assert_array_equal(arrays[0], data)


def test_written_date_none_reads_as_none_and_files_from_us_keep_marker_samples(tmp_path: Path) -> None:
    data = np.full((10, 3), 1000, dtype=np.int32)
    path = tmp_path / "plain.dzt"
    write_dzt(path, data, range_ns=5.0, bits=32)
    dzt = read_dzt(path)
    assert dzt.header.created is None and dzt.header.system is None
    assert (dzt.as_float() == 1000.0).all()  # no GSSI counter/marks here: nothing neutralised


# --- truncated, foreign and corrupt files -------------------------------------------------------


def test_zero_byte_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.dzt"
    path.write_bytes(b"")
    with pytest.raises(DataFormatError, match=r"empty \(0 bytes\).*1024 bytes missing"):
        read_dzt(path)


def test_header_cut_short(tmp_path: Path) -> None:
    path = tmp_path / "cut.dzt"
    path.write_bytes(small_file_bytes()[:700])
    with pytest.raises(DataFormatError, match=r"700 bytes long.*324 bytes missing"):
        read_dzt(path)
    path.write_bytes(small_file_bytes()[:1500])  # second channel's header cut
    with pytest.raises(DataFormatError, match=r"2 channel\(s\) and data from byte 2048.*548 bytes missing"):
        read_dzt(path)


def test_header_only_file(tmp_path: Path, real_dzt: Path) -> None:
    path = tmp_path / "header_only.dzt"
    path.write_bytes(real_dzt.read_bytes()[:1024])
    with pytest.raises(DataFormatError, match=r"no complete trace: 0 data bytes.*needs 1024"):
        read_dzt(path)


def test_data_cut_mid_trace_says_how_many_bytes(tmp_path: Path, real_dzt: Path) -> None:
    path = tmp_path / "cut_mid_trace.dzt"
    path.write_bytes(real_dzt.read_bytes()[:-300])  # scans are 1024 bytes: 724 extra, 300 missing
    with pytest.raises(DataFormatError, match=r"724 bytes extra after 1039 whole scans, 300 bytes missing"):
        read_dzt(path)
    dzt = read_dzt(path, allow_partial=True)
    assert (dzt.header.traces, dzt.dropped_bytes) == (1039, 724)
    np.testing.assert_array_equal(dzt.channels[0], read_dzt(real_dzt).channels[0][:, :1039])


def test_non_dzt_file_is_refused_by_its_tag(tmp_path: Path) -> None:
    path = tmp_path / "photo.dzt"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(4000))
    with pytest.raises(DataFormatError, match=r"not a GSSI DZT file: header tag 0x5089"):
        read_dzt(path)


@pytest.mark.parametrize(
    ("offset", "value", "message"),
    [
        (6, struct.pack("<h", 12), r"rh_bits=12"),
        (52, struct.pack("<h", 0), r"rh_nchan=0"),
        (52, struct.pack("<h", 300), r"rh_nchan=300"),
        (4, struct.pack("<h", 1), r"rh_nsamp=1 \(expected 2\.\.65535"),
        (26, struct.pack("<f", float("nan")), r"rhf_range=nan"),
        (26, struct.pack("<f", 1e5), r"rhf_range=100000 ns \(expected 0 < range <= 10000 ns\)"),
        (26, struct.pack("<f", 1e-6), r"sample interval of 1\.25e-07 ns"),
        (2, struct.pack("<h", 1), r"rh_data=1 puts the data at byte 1024, inside the 2 channel header"),
    ],
)
def test_absurd_header_values_are_named(offset: int, value: bytes, message: str) -> None:
    raw = bytearray(small_file_bytes())
    raw[offset : offset + len(value)] = value
    with pytest.raises(DataFormatError, match=rf"corrupt DZT header: .*{message}"):
        parse_dzt(bytes(raw))


def test_missing_file_is_a_data_format_error(tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match=r"cannot read DZT file .*nope\.dzt"):
        read_dzt(tmp_path / "nope.dzt")


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=3000))
def test_random_bytes_raise_only_data_format_error(raw: bytes) -> None:
    with contextlib.suppress(DataFormatError):
        parse_dzt(raw)


@settings(max_examples=400, deadline=None)
@given(
    st.lists(st.tuples(st.integers(0, 127), st.integers(0, 255)), min_size=1, max_size=6),
    st.integers(1100, len(small_file_bytes())),
    st.booleans(),
)
def test_mutated_headers_raise_only_data_format_error(
    edits: list[tuple[int, int]], length: int, allow_partial: bool
) -> None:
    raw = bytearray(small_file_bytes()[:length])
    for position, byte in edits:
        raw[position] = byte
    try:
        dzt = parse_dzt(bytes(raw), allow_partial=allow_partial)
    except DataFormatError:
        return
    header = dzt.header
    used = header.data_offset + header.traces * header.channels * header.samples * header.bits // 8
    assert header.traces >= 1 and used + dzt.dropped_bytes == len(raw)
    assert all(channel.shape == (header.samples, header.traces) for channel in dzt.channels)


# --- writer checks, atomicity and summaries ------------------------------------------------------


@pytest.mark.parametrize(
    ("data", "kwargs", "message"),
    [
        (np.zeros((4, 4)), {"bits": 12}, r"bits=12: choose 8, 16 or 32"),
        (np.full((4, 4), np.nan), {}, r"NaN or infinity"),
        (np.full((4, 4), 70000), {}, r"span 70000\.\.70000, outside the 16-bit range 0\.\.65535"),
        (np.zeros((4, 4)), {"antenna": "a very long antenna name"}, r"at most 14 ASCII"),
        ([np.zeros((4, 4))] * 5, {}, r"5 channels"),
        ([np.zeros((4, 4)), np.zeros((4, 5))], {}, r"same shape"),
        (np.zeros((4, 4)), {"range_ns": 0.0}, r"range_ns=0\.0"),
        (np.zeros((4, 4)), {"created": datetime(1975, 1, 1)}, r"years 1980-2107"),
    ],
)
def test_write_refuses_what_it_cannot_store(tmp_path: Path, data: Any, kwargs: dict[str, Any], message: str) -> None:
    arguments: dict[str, Any] = {"range_ns": 10.0, **kwargs}
    with pytest.raises(DataFormatError, match=message):
        write_dzt(tmp_path / "bad.dzt", data, **arguments)
    assert list(tmp_path.iterdir()) == []


def test_write_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "line.dzt"
    path.write_bytes(b"previous contents")

    def failing_replace(src: str, dst: Path) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        write_dzt(path, np.zeros((4, 4), dtype=np.uint16), range_ns=10.0)
    assert path.read_bytes() == b"previous contents"
    assert [p.name for p in tmp_path.iterdir()] == ["line.dzt"]  # no temp file left behind


def test_header_info_and_format_info(real_dzt: Path) -> None:
    header = read_dzt(real_dzt).header
    info = header_info(header)
    assert json.loads(json.dumps(info)) == info
    assert info["created"] == "2017-03-21T00:36:46" and info["dt_ns"] == 0.09375
    table = format_info(header)
    for expected in (
        "SIR-3000",
        "400MHz",
        "512 per trace",
        "1040 per channel",
        "16 (unsigned)",
        "48 ns (dt 0.09375 ns)",
        "traces per metre   50",
        "2017-03-21 00:36:46",
    ):
        assert expected in table
