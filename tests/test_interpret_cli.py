"""`gprbot interpret FILE` end to end on a real file: the chain's detections.json, pictures and report."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from gprbot.cli import main
from validation.cases import REAL_DATA

SSMINI = REAL_DATA / "gssi_ssmini_rebar_ietgpr" / "File____002.DZT"
BARS_M = (0.08, 0.30, 0.48, 0.69, 0.88, 1.11, 1.30)  # the README's positions, ±2 cm


@pytest.mark.skipif(not SSMINI.exists(), reason="shared/data/real is not beside the checkout")
def test_interpret_reports_the_mesh_as_rebars_and_how_the_velocity_was_found(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["interpret", str(SSMINI), "--out", str(tmp_path)]) == 0
    report = capsys.readouterr().out
    assert "rebar" in report and "velocity" in report
    result = json.loads((tmp_path / "detections.json").read_text())
    bars = [b["x_m"] for b in result["rebars"]]
    assert all(any(abs(b - x) <= 0.02 for b in bars) for x in BARS_M)
    assert len(result["detections"]) <= 1  # pipes: at most one false one on this line
    assert result["velocity_source"] == "estimated" and "migration focus" in result["velocity_method"]
    votes = result["velocity_votes"]  # each hyperbola's vote, listed: the estimate is their weighted median
    counted = re.search(r"focus of (\d+|one) diffraction", result["velocity_method"])
    assert counted and len(votes) == (1 if counted[1] == "one" else int(counted[1]))
    assert min(b["v_m_per_ns"] for b in votes) <= result["velocity_m_per_ns"] <= max(b["v_m_per_ns"] for b in votes)
    assert all(b["weight"] > 0 and 0.0 <= b["x_m"] <= 1.5 for b in votes)
    assert ("votes (m/ns at x m" in report) == (len(votes) > 1)  # the report lists them when there is a choice
    assert result["time_zero_from"] == "direct-wave envelope peak"
    for key in ("cover_m", "radius_sigma_m", "radius_supported", "fill_hint", "confidence", "found_by"):
        assert key in result["rebars"][0]
    assert (tmp_path / "bscan.png").stat().st_size > 0 and (tmp_path / "section.png").stat().st_size > 0
    # --json prints detections.json itself (and nothing else) on stdout
    assert main(["interpret", str(SSMINI), "--out", str(tmp_path / "j"), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads((tmp_path / "j" / "detections.json").read_text())


@pytest.mark.skipif(not SSMINI.exists(), reason="shared/data/real is not beside the checkout")
def test_interpret_refuses_an_impossible_antenna_geometry(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["interpret", str(SSMINI), "--height", "-0.1", "--out", str(tmp_path)]) == 2  # a usage error
    assert "--height" in capsys.readouterr().err


FDTD_PIPE = Path(__file__).resolve().parents[1] / "validation" / "fdtd" / "data" / "metal_pipe_2600.DZT"
FDTD_GEOMETRY = ["--height", "0.01", "--offset", "0.03"]  # its truth JSON's antenna
FDTD_V = 0.12239  # m/ns; the pipe's top lies 8.5 cm down at x 0.22 m


def test_a_known_top_calibrates_the_velocity_and_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["interpret", str(FDTD_PIPE), *FDTD_GEOMETRY, "--json"]
    assert main([*args, "--known-top", "0.22:0.085", "--out", str(tmp_path / "k")]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["velocity_source"] == "calibrated" and "known top at x 0.220 m" in result["velocity_method"]
    assert abs(result["velocity_m_per_ns"] / FDTD_V - 1.0) <= 0.05  # -2.8 % (the estimate alone: +6.5 %)
    assert 0 < result["velocity_sigma_m_per_ns"] < 0.1 * FDTD_V
    assert not any("--velocity" in n for n in result["notes"])  # the reader's advice is answered
    (pipe,) = result["detections"]
    assert abs(pipe["x_m"] - 0.22) <= 0.01 and abs(pipe["cover_m"] - 0.085) <= 0.01
    # Nothing near the given position: the velocity is estimated as before, and a note says why.
    assert main([*args, "--known-top", "0.02:0.085", "--out", str(tmp_path / "far")]) == 0
    far = json.loads(capsys.readouterr().out)
    assert far["velocity_source"] == "estimated" and any("the known top there" in n and "was not used" in n
                                                         for n in far["notes"])
    # A depth no velocity in bounds explains (5 m, not 5 cm): not used either, and said so.
    assert main([*args, "--known-top", "0.22:5", "--out", str(tmp_path / "deep")]) == 0
    deep = json.loads(capsys.readouterr().out)
    assert deep["velocity_source"] == "estimated" and any("check the depth" in n for n in deep["notes"])


@pytest.mark.parametrize("bad", [["--known-top", "0.22"], ["--known-top", "0.22:-0.1"],
                                 ["--known-top", "0.22:0.085", "--velocity", "0.1"]])
def test_a_malformed_or_conflicting_known_top_is_a_usage_error(bad: list[str], tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["interpret", str(FDTD_PIPE), *bad, "--out", str(tmp_path)])
    assert exit_.value.code == 2
    assert "--known-top" in capsys.readouterr().err


def test_two_known_tops_calibrate_velocity_and_time_zero(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = FDTD_PIPE.with_name("overlapping_flanks_2000.DZT")  # tops 6.5 cm at x 0.2 m and 16 cm at x 0.3 m
    assert main(["interpret", str(scene), "--height", "0.01", "--offset", "0.032", "--json", "--out", str(tmp_path),
                 "--known-top", "0.2:0.065", "--known-top", "0.3:0.16"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["velocity_source"] == "calibrated" and "2 known tops" in result["velocity_method"]
    assert abs(result["velocity_m_per_ns"] / 0.12239 - 1.0) <= 0.03  # +0.8 % (either top alone: -10 and -4 %)
    assert "moved" in result["time_zero_from"]


def test_migrationnet_reports_a_pipe_once_and_says_which_echo_it_dropped(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An FDTD dev scene (a 6.4 cm PVC pipe at 10 cm): MigrationNet also marks the pipe's echo 18 cm under it,
    which the chain's hyperbolas do not confirm; detections.json has the pipe only, and a note says why."""
    scene = Path(__file__).resolve().parents[1] / "validation" / "fdtd" / "data" / "random_25.DZT"
    config = tmp_path / "learned.yaml"
    config.write_text("interpretation:\n  method: migrationnet\n")
    assert main(["interpret", str(scene), "--out", str(tmp_path / "out"), "--config", str(config),
                 "--velocity", "0.124076", "--height", "0.0375", "--offset", "0.09", "--frequency", "704.5"]) == 0
    result = json.loads((tmp_path / "out" / "detections.json").read_text())
    assert result["method"] == "migrationnet"
    (pipe,) = result["detections"]
    assert abs(pipe["x_m"] - 0.169) <= 0.03 and abs(pipe["depth_m"] - 0.100) <= 0.03
    # the blob's half-height is no measured radius: the pipe says so with the chain's keys
    assert pipe["radius_from"] == "MigrationNet pipe mask" and pipe["radius_supported"] is False
    assert pipe["cover_m"] == pytest.approx(pipe["depth_m"] - pipe["radius_m"], abs=1e-4)
    assert pipe["radius_sigma_m"] > 0 and pipe["found_by"] == "migrationnet"
    (note,) = [n for n in result["notes"] if "not reported" in n]
    assert "echoes" in note and "under the pipe at depth 0.1" in note
    assert "not reported" in capsys.readouterr().out
