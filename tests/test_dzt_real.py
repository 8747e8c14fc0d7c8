"""Every real DZT in ../shared/data/real: what the READMEs say the headers hold, sample-for-sample
agreement with readgssi (an independent reader), marks, and the real DZX sidecars."""

from __future__ import annotations

import contextlib
import io
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from readgssi.dzt import readdzt

from gprbot.gpr.antennas import antenna_frequency_mhz
from gprbot.gpr.dzt import read_dzt, write_dzt
from gprbot.gpr.dzt_sidecars import parse_dzx, parse_mrk

from .conftest import SHARED_DATA

REAL = SHARED_DATA / "real"
FILES = {
    "sir3000": REAL / "FILE____032.DZT",
    "ssmini1": REAL / "gssi_ssmini_rebar_ietgpr" / "File____001.DZT",
    "ssmini2": REAL / "gssi_ssmini_rebar_ietgpr" / "File____002.DZT",
    "8bit": REAL / "gssi_400mhz_8bit_matgpr" / "testdata.dzt",
    "tag0700": REAL / "gssi_900mhz_16bit_gprpy_pr" / "FILE____238.DZT",
}
# (system, tag, antenna MHz, bits, samples, traces, range ns, spm, eps_r, marks) from the READMEs.
EXPECTED = {
    "sir3000": ("SIR-3000", 0x0700, 400, 16, 512, 1040, 48.0, 50.0, 6.0, list(range(0, 1001, 100))),
    "ssmini1": ("StructureScan Mini", 0x00FF, 1600, 32, 256, 863, 10.0, 800.0, 6.0, list(range(159, 863, 160))),
    "ssmini2": ("StructureScan Mini", 0x00FF, 1600, 32, 256, 1187, 10.0, 800.0, 6.0, list(range(159, 1187, 160))),
    "8bit": (
        "GSSI unit (system code 10)", 0x00FF, 400, 8, 512, 2147, 100.0, 0.0, 9.0,
        [193, 357, 526, 672, 839, 989, 1145, 1291, 1444, 1598, 1735, 1887, 2029],
    ),
    "tag0700": (
        "SIR-3000", 0x0700, 900, 16, 1024, 1586, 30.0, 100.0, 6.25,
        [0, 1, *range(100, 1101, 100), 1197, 1300, 1400, 1500],
    ),
}  # fmt: skip


def real(name: str) -> Path:
    path = FILES[name]
    if not path.exists():
        pytest.skip(f"{path} not present")
    return path


def readgssi_view(path: Path) -> tuple[dict[str, Any], list[NDArray[Any]]]:
    """readgssi's reading with zero=0: its default cuts rh_zero samples (128 of the 8-bit file's 512)."""
    with contextlib.redirect_stdout(io.StringIO()):
        header, arrays, _ = readdzt(str(path), zero=[0, 0, 0, 0])
    return header, [arrays[k] for k in range(header["rh_nchan"])]


@pytest.mark.parametrize("name", sorted(FILES))
def test_real_file_header_marks_and_warnings(name: str) -> None:
    dzt = read_dzt(real(name))
    h = dzt.header
    system, tag, mhz, bits, samples, traces, range_ns, spm, eps_r, marks = EXPECTED[name]
    assert (h.system, h.tag, h.bits, h.samples, h.traces) == (system, tag, bits, samples, traces)
    assert (h.range_ns, h.traces_per_m, h.eps_r) == (range_ns, spm, eps_r)
    assert antenna_frequency_mhz(h.antenna) == mhz
    assert list(dzt.marks) == marks and dzt.mark_source == "trace headers"
    # only what the unit really left unset is warned about
    expect = {"8bit": ["traces per metre is 0"], "ssmini1": ["rhf_position is negative"]}
    expect["ssmini2"] = expect["ssmini1"]
    assert [w.split(":")[0].split(" (")[0] for w in dzt.warnings] == expect.get(name, [])


@pytest.mark.parametrize("name", sorted(FILES))
def test_real_file_agrees_with_readgssi_sample_for_sample(name: str) -> None:
    path = real(name)
    dzt = read_dzt(path)
    theirs, arrays = readgssi_view(path)
    assert (theirs["rh_nsamp"], theirs["rh_bits"], theirs["shape"][1]) == (
        dzt.header.samples,
        dzt.header.bits,
        dzt.header.traces,
    )
    assert theirs["rhf_range"] == dzt.header.range_ns and theirs["dzt_spm"] == dzt.header.traces_per_m
    assert theirs["rh_ant"][0] == dzt.header.antenna and theirs["data_offset"] == dzt.header.data_offset
    np.testing.assert_array_equal(dzt.channels[0], arrays[0])


def test_8bit_file_rh_zero_is_not_the_time_zero_or_offset() -> None:
    path = real("8bit")
    dzt = read_dzt(path)
    assert dzt.header.zero == 128 and dzt.header.gain_db == (3.0, 44.0, 50.0, 55.0, 60.0)
    assert dzt.header.text == "Try and try ..."
    with contextlib.redirect_stdout(io.StringIO()):
        _, default = readdzt(str(path))[:2]  # readgssi's default: rh_zero as time zero
    assert default[0].shape[0] == 384  # the pitfall the README describes; ours keeps all 512
    assert dzt.channels[0].shape == (512, 2147)
    signal = dzt.as_float()
    assert abs(float(signal[:, 2:].mean())) < 5.0  # offset 128 removed, not rh_zero


def test_8bit_mrk_file_agrees_with_the_trace_header_marks(tmp_path: Path) -> None:
    mrk = real("8bit").with_suffix(".mrk")
    assert parse_mrk(mrk.read_bytes()) == read_dzt(real("8bit")).marks
    # without the mark words (a unit that stores none), the .MRK file gives the marks
    copy = tmp_path / "testdata.dzt"
    raw = bytearray(real("8bit").read_bytes())
    dzt = read_dzt(real("8bit"))
    for k in range(dzt.header.traces):
        raw[1024 + 512 * k + 1] = 0xF0
    copy.write_bytes(bytes(raw))
    shutil.copy(mrk, tmp_path / "testdata.mrk")
    again = read_dzt(copy)
    assert again.marks == dzt.marks and again.mark_source == "MRK file"


def test_real_dzx_sidecars() -> None:
    folder = REAL / "gssi_900mhz_16bit_gprpy_pr"
    if not folder.exists():
        pytest.skip("real DZX files not present")
    for name, last, jumps in (("FILE____176.DZX", 2317, 1), ("FILE____177.DZX", 2313, 0)):
        info = parse_dzx((folder / name).read_bytes(), name)
        assert info.dielectric == 6.25 and info.units_per_scan == 0.01 and info.horizontal_unit == "m"
        assert info.unit_m == 1.0 and len(info.waypoints) == 25 and info.scan_range == (0, last)
        # distance marks, and (177) an unlabelled end-of-line waypoint that still carries a distance
        assert {w.mark for w in info.waypoints} <= {"Distance", ""} and info.user_marks() == ()
        distance, notes = info.distance_m(last + 1)
        assert distance is not None and distance[100] == 1.0 and distance[0] == 0.0
        assert len(notes) == jumps
    info = parse_dzx((folder / "FILE____176.DZX").read_bytes())
    assert {199, 1197} <= {w.scan for w in info.waypoints}  # the encoder jitter the README names
    distance, notes = info.distance_m(2318)
    assert distance is not None and distance[1197] == 12.0
    assert "2287->2317" in notes[0]  # its last mark jumps from 23 to 30 m in 30 scans


def test_dzx_beside_a_dzt_gives_distances_and_hints(tmp_path: Path) -> None:
    dzx = REAL / "gssi_900mhz_16bit_gprpy_pr" / "FILE____176.DZX"
    if not dzx.exists():
        pytest.skip("real DZX file not present")
    path = tmp_path / "FILE____176.DZT"
    write_dzt(path, np.zeros((64, 2318), dtype=np.uint16), range_ns=30.0, eps_r=6.25)  # spm 0
    shutil.copy(dzx, tmp_path / "FILE____176.DZX")
    dzt = read_dzt(path)
    assert dzt.dzx is not None
    distance = dzt.trace_distance_m()
    assert distance is not None and distance[1000] == 10.0
    assert any("the .DZX gives 0.01 m per scan" in w for w in dzt.warnings)
