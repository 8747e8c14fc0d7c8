"""Truncated, foreign and odd files give one DataFormatError line that says what to do, never a traceback."""

from __future__ import annotations

import builtins
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gprbot.cli import main
from gprbot.errors import DataFormatError
from gprbot.gpr.formats import Radargram, detect_format, read_radargram, write_radargram
from gprbot.gpr.formats.gprmax import read_gprmax
from tests.conftest import SHARED_DATA

REAL = SHARED_DATA / "real"


def line(tmp_path: Path, suffix: str, traces: int = 10, samples: int = 32) -> Path:
    """A small file we wrote, as the starting point of a damaged one."""
    rg = Radargram(samples=np.ones((traces, samples), np.float32), dt_ns=0.1, source_format="test",
                   positions_m=np.arange(traces) * 0.02)
    return write_radargram(tmp_path / f"l{suffix}", rg)[0][0]


@pytest.mark.parametrize("suffix", [".DT1", ".sgy", ".su"])
def test_truncated_file_says_copy_again(suffix: str, tmp_path: Path) -> None:
    path = line(tmp_path, suffix)
    path.write_bytes(path.read_bytes()[:-7])
    with pytest.raises(DataFormatError) as err:
        read_radargram(path, suffix.lstrip(".").lower().replace("sgy", "segy"))
    assert "\n" not in str(err.value) and ("truncated" in str(err.value) or "whole number" in str(err.value))


def test_partial_trace_dropped_on_request(tmp_path: Path) -> None:
    path = line(tmp_path, ".DT1")
    path.write_bytes(path.read_bytes()[:-7])
    assert read_radargram(path, allow_partial=True).traces == 9


def test_foreign_file_is_not_guessed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "photo.png"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 10)
    with pytest.raises(DataFormatError, match="not a GPR file"):
        detect_format(path)
    assert main(["info", str(path)]) == 1
    assert capsys.readouterr().err.count("\n") == 1


def test_missing_sidecars_name_the_fix(tmp_path: Path) -> None:
    path = line(tmp_path, ".DT1")
    path.with_suffix(".HD").unlink()
    assert any("no .HD" in w for w in read_radargram(path).warnings)
    rd3 = tmp_path / "x.rd3"
    rd3.write_bytes(np.zeros(64, "<i2").tobytes())
    with pytest.raises(DataFormatError, match=r"no \.rad header"):
        read_radargram(rd3, "mala")


def test_rad_with_absurd_values(tmp_path: Path) -> None:
    rd3 = tmp_path / "x.rd3"
    rd3.write_bytes(np.zeros(64, "<i2").tobytes())
    for text, match in (("SAMPLES:1e9\nFREQUENCY:1000\n", "samples per trace"),
                        ("SAMPLES:32\nFREQUENCY:1e-30\n", "sample interval"),
                        ("SAMPLES:32\nFREQUENCY:abc\n", "FREQUENCY")):
        rd3.with_suffix(".rad").write_text(text)
        with pytest.raises(DataFormatError, match=match):
            read_radargram(rd3)


def test_too_many_values_refused_before_allocating(tmp_path: Path) -> None:
    path = tmp_path / "huge.rd3"
    path.write_bytes(b"")
    with path.open("r+b") as f:
        f.truncate(2 * 65536 * 2000)  # sparse: 2000 traces of 65536 samples = 131 M values
    path.with_suffix(".rad").write_text("SAMPLES:65536\nFREQUENCY:1000\n")
    with pytest.raises(DataFormatError, match="more than"):
        read_radargram(path)


def test_dzt_channel_option_on_single_channel_formats(tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match="DZT files only"):
        read_radargram(line(tmp_path, ".su"), channel=1)


def test_gprmax_without_h5py_says_what_to_install(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    real_import = builtins.__import__

    def no_h5py(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == "h5py":
            raise ImportError("no h5py")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_h5py)
    with pytest.raises(DataFormatError, match=r"pip install gprbot\[formats\]"):
        read_gprmax(tmp_path / "x.out")


def test_gprmax_without_receivers(tmp_path: Path) -> None:
    import h5py

    path = tmp_path / "empty.out"
    with h5py.File(path, "w") as f:
        f.attrs["dt"] = 1e-12
    assert detect_format(path) == "gprmax"
    with pytest.raises(DataFormatError, match="no /rxs/rx1"):
        read_radargram(path)


def test_su_without_spacing_needs_spacing_for_interpret(tmp_path: Path) -> None:
    src = REAL / "su_trench_pipes_matgpr" / "trench_and_pipes.su"
    if not src.exists():
        pytest.skip("real SU file not present")
    raw = bytearray(src.read_bytes()[: 3 * (240 + 4 * 917)])
    for k in range(3):  # clear d2 and make the coordinates 40 m apart (scalar 0): not a GPR spacing
        raw[k * (240 + 4 * 917) + 188 : k * (240 + 4 * 917) + 192] = bytes(4)
    path = tmp_path / "t.su"
    path.write_bytes(bytes(raw))
    rg = read_radargram(path)
    assert rg.positions_m is None and any("not a GPR trace spacing" in w for w in rg.warnings)
    shutil.copy(path, tmp_path / "u.su")


def test_hdf5_library_crash_is_contained(tmp_path: Path) -> None:
    src = REAL / "gprmax_cylinder_2d" / "cylinder_Bscan_2D_merged.out"
    if not src.exists():
        pytest.skip("real gprMax file not present")
    raw = bytearray(src.read_bytes())
    raw[921] = 104  # found by fuzzing: libhdf5 dies with SIGSEGV on this object header
    path = tmp_path / "damaged.out"
    path.write_bytes(bytes(raw))
    with pytest.raises(DataFormatError, match="HDF5 library failed"):
        read_radargram(path)
