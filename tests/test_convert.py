"""Round trips between the formats we write (DZT, DT1+HD, SEG-Y, SU), `gprbot convert`, and the survey export.

DZT → DT1 → SEG-Y → DZT keeps the samples exactly (16-bit counts are integers, stored as int16 in DT1
and float32 in SEG-Y) and the positions to float32 precision of the DZT's traces per metre (< 1e-6 m
per metre of line); float samples written to DT1 or DZT are scaled to 16-bit full scale, so they come
back within half a count. readgssi reads every DZT we write.
"""

from __future__ import annotations

import contextlib
import io
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import segyio

from gprbot.cli import main
from gprbot.gpr.bscan import BScan
from gprbot.gpr.formats import Radargram, read_radargram, write_radargram
from gprbot.gpr.formats.export import POSES_HEADER, export_survey_lines
from tests.conftest import REAL_DZT, SHARED_DATA


def readgssi_read(path: Path) -> tuple[dict[str, object], np.ndarray]:
    """readgssi's header and channel 0 (samples, traces), its prints and warnings silenced."""
    from readgssi.dzt import readdzt

    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        header, data, _ = readdzt(str(path))
    return header, np.asarray(data[0])


def synthetic(traces: int = 40, samples: int = 64, *, integral: bool = True) -> Radargram:
    """A small line with positions, time zero, frequency and separation."""
    rng = np.random.default_rng(3)
    data = rng.normal(0, 3000, (traces, samples))
    data = np.rint(data) if integral else data / 7.3
    return Radargram(samples=data.astype(np.float32), dt_ns=0.05, source_format="test",
                     positions_m=np.arange(traces) * 0.01, time_zero_ns=1.25, frequency_mhz=900.0,
                     antenna_separation_m=0.06)


@pytest.mark.parametrize("suffix", [".DT1", ".sgy", ".su", ".DZT"])
def test_each_writer_reads_back(suffix: str, tmp_path: Path) -> None:
    rg = synthetic()
    written, _ = write_radargram(tmp_path / f"line{suffix}", rg)
    back = read_radargram(written[0])
    assert np.array_equal(back.samples, rg.samples)
    assert back.dt_ns == pytest.approx(rg.dt_ns, rel=1e-6)
    assert back.positions_m is not None and np.allclose(back.positions_m, rg.positions_m, atol=1e-6)
    if suffix != ".DZT":
        assert back.time_zero_ns == pytest.approx(1.25, abs=0.5 if suffix == ".su" else 1e-6)
    if suffix in (".DT1", ".sgy"):
        assert back.frequency_mhz == 900.0 and back.antenna_separation_m == pytest.approx(0.06)


def test_float_samples_are_scaled_and_dt1_undoes_the_scale(tmp_path: Path) -> None:
    rg = synthetic(integral=False)
    written, notes = write_radargram(tmp_path / "f.DT1", rg)
    scale = 32767 / float(np.abs(rg.samples).max())
    assert any("scaled" in n for n in notes)
    back = read_radargram(written[0]).samples
    assert float(np.abs(back - rg.samples).max()) <= 0.5 / scale + 1e-6


def test_segy_is_rev1_that_segyio_reads(tmp_path: Path) -> None:
    rg = synthetic()
    write_radargram(tmp_path / "l.sgy", rg)
    with segyio.open(str(tmp_path / "l.sgy"), ignore_geometry=True) as f:
        assert np.array_equal(f.trace.raw[:], rg.samples)
        assert f.bin[segyio.BinField.Interval] == 50 and f.bin[segyio.BinField.SEGYRevision] == 1
        assert list(f.attributes(segyio.TraceField.CDP_X)[:5]) == [0, 10, 20, 30, 40]
        assert "GPRBOT DT_NS 0.05" in bytes(f.text[0]).decode("ascii")


def test_dzt_to_dt1_to_segy_to_dzt_keeps_samples_and_positions(real_dzt: Path, tmp_path: Path) -> None:
    first = read_radargram(real_dzt)
    assert main(["convert", str(real_dzt), str(tmp_path / "a.DT1")]) == 0
    assert main(["convert", str(tmp_path / "a.DT1"), str(tmp_path / "b.sgy")]) == 0
    assert main(["convert", str(tmp_path / "b.sgy"), str(tmp_path / "c.DZT")]) == 0
    last = read_radargram(tmp_path / "c.DZT")
    assert np.array_equal(last.samples, first.samples)
    assert first.positions_m is not None and last.positions_m is not None
    assert float(np.abs(last.positions_m - first.positions_m).max()) < 1e-4
    assert last.dt_ns == pytest.approx(first.dt_ns, rel=1e-9) and last.frequency_mhz is None
    header, data = readgssi_read(tmp_path / "c.DZT")
    assert data.shape == first.samples.T.shape and header["rh_nsamp"] == first.n_samples
    assert np.array_equal(data.astype(np.float64) - 32768, first.samples.T)
    assert read_radargram(tmp_path / "c.DZT").antenna == "400MHz"


REAL_OTHERS = [
    SHARED_DATA / "real" / "pulseekko_dt1_rgpr_negative" / "yyline3.DT1",
    SHARED_DATA / "real" / "mala_rd3_250mhz_matgpr" / "DAT_0097.rd3",
    SHARED_DATA / "real" / "su_trench_pipes_matgpr" / "trench_and_pipes.su",
    SHARED_DATA / "real" / "gprmax_cylinder_2d" / "cylinder_Bscan_2D_merged.out",
]


@pytest.mark.parametrize("path", REAL_OTHERS, ids=["dt1", "rd3", "su", "gprmax"])
def test_real_files_convert_to_every_format_and_readgssi_reads_the_dzt(path: Path, tmp_path: Path) -> None:
    if not path.exists():
        pytest.skip(f"{path} not present")
    source = read_radargram(path)
    for suffix in (".DT1", ".sgy", ".su", ".DZT"):
        assert main(["convert", str(path), str(tmp_path / f"out{suffix}")]) == 0
        back = read_radargram(tmp_path / f"out{suffix}")
        assert back.samples.shape == source.samples.shape
        if suffix in (".sgy", ".su") or np.array_equal(source.samples, np.rint(source.samples)):
            assert np.allclose(back.samples, source.samples, rtol=1e-6, atol=1e-6 * float(np.abs(source.samples).max()))
    _, data = readgssi_read(tmp_path / "out.DZT")
    assert data.shape == source.samples.T.shape


def test_convert_refuses_a_read_only_target(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_radargram(tmp_path / "a.su", synthetic())
    assert main(["convert", str(tmp_path / "a.su"), str(tmp_path / "b.rd3")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and ".DZT, .DT1" in err


def test_survey_export_writes_dzt_dt1_and_poses(tmp_path: Path) -> None:
    n = 50
    pos = np.column_stack([np.linspace(0.0, 1.0, n) ** 1.1, np.full(n, 0.3), np.zeros(n)])
    data = np.random.default_rng(1).normal(0, 5, (n, 128)).astype(np.float32)
    bscan = BScan(data, 0.0234375, 1.0, pos, np.arange(n) * 0.05)
    files = export_survey_lines(tmp_path, {3: bscan}, {"centre_frequency_mhz": 900.0, "tx_rx_offset_m": 0.05})
    assert sorted(f.name for f in files) == ["line-03-poses.csv", "line-03.DT1", "line-03.DZT", "line-03.HD"]
    dt1 = read_radargram(tmp_path / "line-03.DT1")
    assert dt1.positions_m is not None and np.allclose(dt1.positions_m, bscan.along_track_m(), atol=1e-6)
    assert dt1.time_zero_ns == pytest.approx(1.0) and dt1.frequency_mhz == 900.0
    assert float(np.abs(dt1.samples - data).max()) < 0.5 * float(np.abs(data).max()) / 32767 + 1e-6
    header, raw = readgssi_read(tmp_path / "line-03.DZT")
    assert raw.shape == (128, n) and header["rhf_spm"] == pytest.approx((n - 1) / bscan.along_track_m()[-1], rel=1e-5)
    rows = (tmp_path / "line-03-poses.csv").read_text().splitlines()
    assert rows[0] == POSES_HEADER and len(rows) == n + 1
    last = [float(v) for v in rows[-1].split(",")]
    assert last[1] == pytest.approx(2.45) and last[3:] == pytest.approx(pos[-1].tolist(), abs=1e-4)


def test_info_json_of_a_written_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_radargram(tmp_path / "x.sgy", synthetic())
    assert main(["info", str(tmp_path / "x.sgy"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "segy" and info["dt_ns"] == 0.05 and info["warnings"] == []
    assert REAL_DZT.name.endswith(".DZT")
