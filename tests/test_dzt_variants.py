"""DZT header variants built byte by byte from the public layout: SIR-4000, a 1999 file, old tags,
extended headers, multi-channel files, fields left at 0 or nonsense, and the bounds.

`build_dzt` is the one place these tests (and test_dzt_fuzz / test_dzt_sidecars) make files the
project has no real example of; it writes every field at the offset GSSI's "RADAN DZT File Format"
gives it, independently of gprbot's own writer.
"""

from __future__ import annotations

import contextlib
import io
import struct
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from readgssi.dzt import readdzt

from gprbot.errors import DataFormatError
from gprbot.gpr.antennas import antenna_frequency_mhz
from gprbot.gpr.bscan import bscan_from_dzt
from gprbot.gpr.dzt import dzt_info, format_dzt_info, parse_dzt, read_dzt, write_dzt
from gprbot.gpr.dzt_header import BOUNDS, decode_date, encode_date, is_known_tag

STORED = {8: np.uint8, 16: np.uint16, 32: np.int32}


def build_dzt(
    channels: list[NDArray[Any]],
    *,
    bits: int,
    tag: int = 0x00FF,
    rh_data: int = 1024,
    range_ns: float = 50.0,
    sps: float = 64.0,
    spm: float = 100.0,
    mpm: float = 0.0,
    position: float = 0.0,
    eps_r: float = 6.0,
    zero: int = 0,
    system: int = 0,
    version: int = 1,
    antennas: tuple[str, ...] = ("400MHz",),
    created: datetime | None = None,
    extra_blocks: int = 0,
    gain_db: tuple[float, ...] = (),
    text: bytes = b"",
) -> bytes:
    """A DZT file: one 1024-byte header per channel (+ extra blocks), then interleaved scans.

    `channels` are (samples, traces) arrays already in the stored type (uint8/uint16/int32).
    """
    samples = channels[0].shape[0]
    headers = bytearray()
    for k in range(len(channels)):
        h = bytearray(1024)
        struct.pack_into("<HhHhh5fh", h, 0, tag, rh_data, samples, bits, zero, sps, spm, mpm, position, range_ns, 0)
        cdt = encode_date(created)
        struct.pack_into("<II", h, 32, cdt, cdt)
        rgain = 128 if gain_db else 0
        nrgain = 2 + 4 * len(gain_db) if gain_db else 0
        text_at = 128 + nrgain if text else 0
        struct.pack_into("<7h", h, 40, rgain, nrgain, text_at, len(text), 0, 0, len(channels))
        struct.pack_into("<3f", h, 54, eps_r, 0.0, 0.3 / max(eps_r, 1.0) ** 0.5 * range_ns / 2)
        if gain_db:
            struct.pack_into(f"<h{len(gain_db)}f", h, rgain, len(gain_db), *gain_db)
        if text:
            h[text_at : text_at + len(text)] = text
        h[98:112] = antennas[k % len(antennas)].encode("ascii").ljust(14, b"\0")
        h[113] = system << 3 | version
        h[114:126] = b"SYNTH".ljust(12, b"\0")
        headers += h
    headers += b"\0" * 1024 * extra_blocks
    scans = np.stack([np.asarray(c, dtype=STORED[bits]) for c in channels]).transpose(2, 0, 1)
    return bytes(headers) + np.ascontiguousarray(scans).astype(f"<{np.dtype(STORED[bits]).str[1:]}").tobytes()


def unit_traces(samples: int, traces: int, bits: int, rng: np.random.Generator, mark_word: int = 0) -> NDArray[Any]:
    """A control unit's channel: trace counter in sample 0, mark word every 50th trace in sample 1."""
    if bits == 32:
        data = rng.integers(-(2**20), 2**20, size=(samples, traces)).astype(np.int32)
    else:
        centre = 1 << (bits - 1)
        data = (centre + rng.integers(-centre // 4, centre // 4, size=(samples, traces))).astype(STORED[bits])
    data[0] = np.arange(traces) % (1 << min(bits, 31))
    data[1] = 0
    data[1, ::50] = np.array(mark_word, dtype=np.int64).astype(STORED[bits])
    return data


def sir4000_bytes(traces: int = 120, channels: int = 1) -> bytes:
    """A SIR-4000 file as the issue describes it: tag 0x07FF, 32-bit, 2048 samples, GPS-capable."""
    rng = np.random.default_rng(4000)
    mark = np.array(0xE4000000, dtype=np.uint32).view(np.int32)
    data = [unit_traces(2048, traces, 32, rng, int(mark)) for _ in range(channels)]
    return build_dzt(
        data, bits=32, tag=0x07FF, range_ns=100.0, sps=120.0, spm=40.0, mpm=1.0, eps_r=6.5, system=8, version=2,
        antennas=("50400S", "62000-003"), created=datetime(2021, 6, 14, 10, 22, 30),
    )  # fmt: skip


def file_1999_bytes(tag: int = 0xF0FF, rh_data: int = 1024) -> bytes:
    """A 1999 SIR-2000 file: old tag, time-triggered (spm 0), eps_r 0, mpm 0, 8-bit with rh_zero 0x80."""
    rng = np.random.default_rng(1999)
    data = unit_traces(256, 80, 8, rng, 0xE8)
    data[0] = 0xFF
    data[1] = np.where(np.arange(80) % 50 == 0, 0xE8, 0xF0)
    return build_dzt(
        [data], bits=8, tag=tag, rh_data=rh_data, range_ns=80.0, sps=32.0, spm=0.0, eps_r=0.0, zero=0x80,
        system=2, antennas=("3207",), created=datetime(1999, 8, 3, 15, 4, 12),
    )  # fmt: skip


def readgssi_arrays(path: Path) -> tuple[dict[str, Any], list[NDArray[Any]]]:
    """readgssi's reading of a file, all samples (zero=0 stops it cutting rh_zero samples), quietly."""
    with contextlib.redirect_stdout(io.StringIO()):
        header, arrays, _ = readdzt(str(path), zero=[0, 0, 0, 0])
    return header, [arrays[k] for k in range(header["rh_nchan"])]


# --- SIR-4000 ------------------------------------------------------------------------------------


@pytest.mark.parametrize("channels", [1, 2])
def test_sir4000_file_reads_and_agrees_with_readgssi(tmp_path: Path, channels: int) -> None:
    path = tmp_path / "FILE____001.DZT"
    path.write_bytes(sir4000_bytes(channels=channels))
    dzt = read_dzt(path)
    h = dzt.header
    assert (h.tag, h.system, h.bits, h.samples, h.traces, h.channels) == (0x07FF, "SIR-4000", 32, 2048, 120, channels)
    assert h.gps_capable and h.antennas == ("50400S", "62000-003")[:channels]
    assert h.created == datetime(2021, 6, 14, 10, 22, 30) and h.marks_per_m == 1.0
    assert dzt.marks == tuple(range(0, 120, 50)) and dzt.mark_source == "trace headers"
    assert dzt.warnings == ()
    assert antenna_frequency_mhz(h.antenna) == 400.0
    theirs, arrays = readgssi_arrays(path)
    assert theirs["rh_nsamp"] == 2048 and theirs["rh_system"] == 8
    for k in range(channels):
        np.testing.assert_array_equal(dzt.channels[k], arrays[k])
    assert not dzt.as_float(0)[:, :2].any()  # counter and mark word neutralised


def test_tag_0x07ff_was_the_issue_and_is_now_a_dzt_tag() -> None:
    for tag in (0x00FF, 0x07FF, 0x01FF, 0x0700, 0x0100, 0xF0FF, 0xF3FF, 0xFFFF):
        assert is_known_tag(tag), hex(tag)
    for tag in (0x0000, 0x5089, 0x10FF, 0x00FE, 0x7F00, 0x1000):
        assert not is_known_tag(tag), hex(tag)


# --- the 1999 file and other old headers -----------------------------------------------------------


@pytest.mark.parametrize("tag", [0xF0FF, 0xF2FF, 0x00FF])
def test_1999_file_reads_with_warnings_not_as_corrupt(tmp_path: Path, tag: int) -> None:
    path = tmp_path / "OLD99.DZT"
    path.write_bytes(file_1999_bytes(tag))
    dzt = read_dzt(path)
    h = dzt.header
    assert (h.system, h.bits, h.samples, h.traces, h.eps_r, h.traces_per_m) == ("SIR-2000", 8, 256, 80, 0.0, 0.0)
    assert h.created == datetime(1999, 8, 3, 15, 4, 12) and h.zero == 0x80
    text = " ".join(dzt.warnings)
    assert "eps_r is 0" in text and "--velocity" in text
    assert "traces per metre is 0" in text and "--spacing" in text
    assert dzt.marks == (0, 50)  # 0xE8 on marked traces, 0xF0 elsewhere
    # the binary offset is 128 whatever rh_zero says
    np.testing.assert_array_equal(dzt.as_float()[:, 2:], dzt.channels[0][2:].T.astype(np.float32) - 128)
    # readgssi cannot open this file: it divides by eps_r (ZeroDivisionError, even with epsr=...),
    # so it reads a copy whose eps_r is 6; the samples are the same bytes.
    patched = bytearray(path.read_bytes())
    struct.pack_into("<f", patched, 54, 6.0)
    copy = tmp_path / "PATCHED.DZT"
    copy.write_bytes(bytes(patched))
    _, arrays = readgssi_arrays(copy)
    np.testing.assert_array_equal(dzt.channels[0], arrays[0])
    assert antenna_frequency_mhz(h.antenna) == 100.0


def test_rh_data_zero_reads_after_the_headers_with_a_warning() -> None:
    dzt = parse_dzt(file_1999_bytes(rh_data=0))
    assert dzt.header.data_offset == 1024 and dzt.header.traces == 80
    assert any("rh_data=0" in w for w in dzt.warnings)


def test_extended_header_blocks_and_range_gain_and_notes(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    data = unit_traces(128, 30, 16, rng, 0x6400)
    raw = build_dzt(
        [data], bits=16, tag=0x0700, rh_data=3, extra_blocks=2, system=3, gain_db=(-2.0, 10.0, 30.5), text=b"line 7\n"
    )
    dzt = parse_dzt(raw)
    assert dzt.header.data_offset == 3072 and dzt.header.gain_db == (-2.0, 10.0, 30.5)
    assert dzt.header.text == "line 7"
    np.testing.assert_array_equal(dzt.channels[0], data)
    table = format_dzt_info(dzt)
    assert "range gain         -2 10 30.5 dB" in table and "notes              line 7" in table


@pytest.mark.parametrize("bits", [8, 16, 32])
@pytest.mark.parametrize("n_channels", [1, 3, 4])
def test_multichannel_unit_files_agree_with_readgssi(tmp_path: Path, bits: int, n_channels: int) -> None:
    rng = np.random.default_rng(bits + n_channels)
    data = [unit_traces(64, 40, bits, rng) for _ in range(n_channels)]
    path = tmp_path / "multi.DZT"
    path.write_bytes(build_dzt(data, bits=bits, system=9, antennas=("5103", "3101", "62000", "51600")))
    dzt = read_dzt(path)
    assert dzt.header.antennas == ("5103", "3101", "62000", "51600")[:n_channels]
    _, arrays = readgssi_arrays(path)
    for k in range(n_channels):
        np.testing.assert_array_equal(dzt.channels[k], data[k])
        np.testing.assert_array_equal(arrays[k], data[k])


# --- zero and nonsense fields: warnings, never "corrupt" -------------------------------------------


@pytest.mark.parametrize(
    ("field", "value", "expected", "says"),
    [
        ("eps_r", 0.0, 0.0, "--velocity"),
        ("eps_r", -3.0, 0.0, "--velocity"),
        ("eps_r", float("nan"), 0.0, "--velocity"),
        ("eps_r", 1e30, 0.0, "--velocity"),
        ("spm", 0.0, 0.0, "--spacing"),
        ("spm", 1e-30, 0.0, "--spacing"),
        ("spm", -5.0, 0.0, "--spacing"),
        ("spm", float("inf"), 0.0, "--spacing"),
        ("sps", 0.0, 0.0, "trace times are unknown"),
        ("sps", -1.0, 0.0, "not a scan rate"),
        ("position", -1.5, -1.5, "direct wave"),
        ("position", 1e9, 0.0, "outside the 50 ns window"),
        ("position", float("nan"), 0.0, "outside the 50 ns window"),
    ],
)
def test_nonsense_descriptive_fields_are_warnings(field: str, value: float, expected: float, says: str) -> None:
    rng = np.random.default_rng(0)
    raw = build_dzt([unit_traces(64, 20, 16, rng)], bits=16, **{field: value})
    dzt = parse_dzt(raw)
    stored = {"eps_r": dzt.header.eps_r, "spm": dzt.header.traces_per_m, "sps": dzt.header.traces_per_s}
    stored["position"] = dzt.header.position_ns
    assert stored[field] == expected
    assert any(says in w for w in dzt.warnings), dzt.warnings


def test_info_json_has_the_warnings(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from gprbot.cli import main

    path = tmp_path / "OLD99.DZT"
    path.write_bytes(file_1999_bytes())
    assert main(["info", str(path), "--json"]) == 0
    import json

    info = json.loads(capsys.readouterr().out)
    assert info["tag"] == "0xF0FF" and info["marks"] == [0, 50]
    assert any("--velocity" in w for w in info["warnings"])
    assert main(["info", str(path)]) == 0
    assert "warning: eps_r is 0" in capsys.readouterr().out
    assert dzt_info(read_dzt(path))["line_length_m"] is None  # time-triggered, no DZX


# --- bounds: one clear line, exit 2 -----------------------------------------------------------------


@pytest.mark.parametrize(
    ("offset", "fmt", "value", "message"),
    [
        (4, "<H", 1, r"rh_nsamp=1 \(expected 2\.\.65535"),
        (6, "<h", 24, r"rh_bits=24"),
        (52, "<h", 17, r"rh_nchan=17"),
        (52, "<h", -1, r"rh_nchan=-1"),
        (26, "<f", 1e5, r"rhf_range=100000 ns"),
        (26, "<f", 0.0, r"rhf_range=0 ns"),
        (26, "<f", float("inf"), r"rhf_range=inf"),
        (26, "<f", 1e-6, r"sample interval of 1\.56e-08 ns"),
        (26, "<f", 9000.0, r"sample interval of 141 ns"),
    ],
)
def test_values_that_size_arrays_are_bounded(offset: int, fmt: str, value: float, message: str) -> None:
    rng = np.random.default_rng(0)
    raw = bytearray(build_dzt([unit_traces(64, 20, 16, rng)], bits=16))
    struct.pack_into(fmt, raw, offset, value)
    with pytest.raises(DataFormatError, match=message) as caught:
        parse_dzt(bytes(raw))
    assert "\n" not in str(caught.value) and "re-export" in str(caught.value)


def test_cli_exit_1_on_a_bounded_value(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from gprbot.cli import main

    rng = np.random.default_rng(0)
    raw = bytearray(build_dzt([unit_traces(64, 20, 16, rng)], bits=16))
    struct.pack_into("<f", raw, 26, 1e-6)
    path = tmp_path / "tiny_window.DZT"
    path.write_bytes(bytes(raw))
    assert main(["info", str(path)]) == 1
    assert "sample interval" in capsys.readouterr().err


def test_bounds_table_names_every_sizing_value() -> None:
    names = {row[0] for row in BOUNDS}
    assert {"rh_bits", "rh_nchan", "rh_nsamp", "rhf_range", "dt = range / samples", "traces"} <= names


def test_bscan_from_a_time_mode_file_asks_for_a_spacing() -> None:
    from gprbot.errors import InterpretationError

    with pytest.raises(InterpretationError, match="trace spacing"):
        bscan_from_dzt(parse_dzt(file_1999_bytes()))


# --- dates and antennas -------------------------------------------------------------------------------


def test_dos_dates_round_trip_and_garbage_is_none() -> None:
    when = datetime(1999, 12, 31, 23, 59, 58)
    assert decode_date(encode_date(when)) == when
    assert decode_date(0) is None and decode_date(0xFFFFFFFF) is None


@pytest.mark.parametrize(
    ("name", "mhz"),
    [
        ("400MHz", 400), ("900 MHz", 900), ("1.5 GHz", 1500), ("1.5/1.6GHz", 1500), ("5103", 400),
        ("5103A", 400), ("3101A", 900), ("62000-003", 2000), ("D50800", 800), ("50270S", 270),
        ("51600S", 1600), ("3207AP", 100), ("400D", 400), ("350HS", 350), ("SS MINI #454\n", 1600),
        ("SSMINIXT", 2700), ("300/800D", 300),
        ("0MHz", None), ("20GHz", None), ("gprMax", None), ("CUSTOM", None), ("3200MLF", None), ("", None),
        ("53101", None), ("1234", None),
    ],
)  # fmt: skip
def test_antenna_names(name: str, mhz: float | None) -> None:
    assert antenna_frequency_mhz(name) == mhz


def test_interpret_file_still_exports_the_antenna_table() -> None:
    from gprbot.apps import interpret_file

    assert interpret_file.antenna_frequency_mhz("3101") == 900.0 and interpret_file.GSSI_ANTENNAS["5103"] == 400


def test_writer_refuses_what_the_reader_would_warn_about(tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match="traces_per_m=1e-30"):
        write_dzt(tmp_path / "x.dzt", np.zeros((8, 4)), range_ns=10.0, traces_per_m=1e-30)
    with pytest.raises(DataFormatError, match="sample interval"):
        write_dzt(tmp_path / "x.dzt", np.zeros((8, 4)), range_ns=1e-6)
    assert list(tmp_path.iterdir()) == []
