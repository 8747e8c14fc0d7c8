"""The non-DZT readers on the real files in ../shared/data/real, checked against their READMEs and segyio/h5py.

An independent reader that is not ours agrees sample for sample on every one of these files
(tools/check_formats_against_impdar.py, run in a scratch venv with ImpDAR 1.2.1; docs/formats.md):
DT1 yyline3 vs ImpDAR load_pe max|diff| 0 (after ImpDAR's own demean), RD3 DAT_0097 vs ImpDAR
load_ramac 0, SU trench_and_pipes vs segyio.su 0, both gprMax files vs ImpDAR load_gprMax (Ez) 0
and vs h5py (the component we read) 0.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import segyio

from gprbot.cli import main
from gprbot.gpr.formats import detect_format, read_radargram
from gprbot.gpr.formats.gprmax import read_gprmax
from tests.conftest import SHARED_DATA

REAL = SHARED_DATA / "real"
DT1 = REAL / "pulseekko_dt1_rgpr_negative" / "yyline3.DT1"
RD3 = REAL / "mala_rd3_250mhz_matgpr" / "DAT_0097.rd3"
SU = REAL / "su_trench_pipes_matgpr" / "trench_and_pipes.su"
GPRMAX_2D = REAL / "gprmax_cylinder_2d" / "cylinder_Bscan_2D_merged.out"
GPRMAX_3D = REAL / "gprmax_gssi1500_cylinder_3d" / "GSSI_1500_cylinder_Bscan_all.out"

pytestmark = pytest.mark.skipif(not REAL.exists(), reason=f"{REAL} not present")


def test_dt1_header_facts() -> None:
    rg = read_radargram(DT1)
    assert detect_format(DT1) == detect_format(DT1.with_suffix(".HD")) == "dt1"
    assert rg.samples.shape == (391, 500) and rg.dt_ns == pytest.approx(0.8)
    assert rg.time_zero_ns == pytest.approx((64.889999 - 1) * 0.8)
    assert rg.positions_m is not None and rg.positions_m[[0, -1]].tolist() == [0.0, 97.5]
    assert rg.frequency_mhz == 100.0 and rg.antenna_separation_m == 1.0
    assert rg.header["bytes_per_point"] == 2 and rg.warnings == ()
    raw = np.frombuffer(DT1.read_bytes(), np.int16).reshape(391, 64 + 500)[:, 64:]
    assert np.array_equal(rg.samples, raw)


def test_mala_header_facts() -> None:
    rg = read_radargram(RD3)
    assert detect_format(RD3) == detect_format(RD3.with_suffix(".rad")) == "mala"
    assert rg.samples.shape == (645, 512)
    assert rg.dt_ns == pytest.approx(1000 / 2610.515625) and rg.window_ns == pytest.approx(196.13, abs=0.01)
    assert rg.frequency_mhz == 250.0 and rg.antenna_separation_m == 0.31
    assert rg.spacing_m() == pytest.approx(0.047766)
    assert np.array_equal(rg.samples, np.fromfile(RD3, "<i2").reshape(645, 512))


def test_su_agrees_with_segyio_and_states_its_time_rule() -> None:
    rg = read_radargram(SU)
    assert detect_format(SU) == "su" and rg.samples.shape == (649, 917)
    with segyio.su.open(str(SU), endian="little", ignore_geometry=True) as f:
        assert np.array_equal(rg.samples, f.trace.raw[:])
    assert rg.dt_ns == pytest.approx(0.097, rel=0.01)  # d1 0.09765625, the dt field 97 ps
    assert any("read as 97 ps" in w for w in rg.warnings)
    assert rg.spacing_m() == pytest.approx(0.04, rel=0.01)  # SU d2, as the README infers


@pytest.mark.parametrize("path", [GPRMAX_2D, GPRMAX_3D], ids=["3.1.7-2d", "prerelease-3d"])
def test_gprmax_agrees_with_h5py(path: Path) -> None:
    rg = read_radargram(path)
    component = {GPRMAX_2D: "Ez", GPRMAX_3D: "Ey"}[path]
    assert rg.header["component"] == component
    with h5py.File(path, "r") as f:
        assert np.array_equal(rg.samples, np.asarray(f[f"rxs/rx1/{component}"]).T)
        assert rg.dt_ns == pytest.approx(float(f.attrs["dt"]) * 1e9)
    assert np.array_equal(read_gprmax(path, component="Ex").samples.shape, rg.samples.shape)


def test_gprmax_scene_from_the_in_file() -> None:
    rg = read_radargram(GPRMAX_2D)
    assert rg.positions_m is not None and rg.spacing_m() == pytest.approx(0.002)
    assert rg.frequency_mhz == 1500.0 and rg.antenna_separation_m == pytest.approx(0.04)
    assert rg.header["first_midpoint_m"][0] == pytest.approx(0.06)  # apex at i = 30: midpoint 0.120
    old = read_radargram(GPRMAX_3D)
    assert old.positions_m is None and any("#python" in w for w in old.warnings)
    assert old.frequency_mhz == 1500.0  # antenna_like_GSSI_1500


@pytest.mark.parametrize("path", [DT1, RD3, SU, GPRMAX_2D], ids=["dt1", "rd3", "su", "gprmax"])
def test_detected_by_content_under_another_name(path: Path, tmp_path: Path) -> None:
    fmt = detect_format(path)
    copy = tmp_path / "renamed.bin"
    shutil.copy(path, copy)
    for side in (".HD", ".rad"):
        if path.with_suffix(side).exists():
            shutil.copy(path.with_suffix(side), copy.with_suffix(side))
    assert detect_format(copy) == fmt
    assert np.array_equal(read_radargram(copy).samples, read_radargram(path).samples)


@pytest.mark.parametrize("path", [DT1, RD3, SU, GPRMAX_2D, GPRMAX_3D], ids=["dt1", "rd3", "su", "2d", "3d"])
def test_info_prints_every_format(path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(path)]) == 0
    assert "samples" in capsys.readouterr().out
    assert main(["info", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == detect_format(path) and info["traces"] == read_radargram(path).traces


def test_interpret_reads_a_gprmax_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["interpret", str(GPRMAX_2D), "--velocity", "0.122", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "(gprmax): 60 traces × 637 samples, 1500 MHz" in out
    assert json.loads((tmp_path / "detections.json").read_text())["format"] == "gprmax"
