"""The `gprbot` command on bad input: one clear error line, a non-zero exit, never a traceback."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gprbot.cli import main
from gprbot.gpr.dzt import write_dzt


def _one_error_line(capsys: pytest.CaptureFixture[str], *needles: str) -> None:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gprbot: error:"), err
    for needle in needles:
        assert needle in err[0]


@pytest.fixture
def dzt(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    path = tmp_path / "line.DZT"
    write_dzt(path, rng.normal(0, 100, (256, 40)).astype(np.float32), range_ns=20.0, traces_per_m=50.0,
              antenna="900MHz")
    return path


def test_info_prints_the_header_and_json(dzt: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(dzt), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["samples"] == 256 and info["traces"] == 40


def test_truncated_and_foreign_files_are_one_clear_error(
    dzt: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cut = tmp_path / "cut.DZT"
    cut.write_bytes(dzt.read_bytes()[:-100])
    for command in (["info", str(cut)], ["interpret", str(cut), "--out", str(tmp_path / "o")]):
        assert main(command) == 1
        _one_error_line(capsys, "truncated", "--allow-partial")
    assert main(["info", str(cut), "--allow-partial"]) == 0
    capsys.readouterr()
    other = tmp_path / "notes.DZT"
    other.write_text("not a radar file at all\n" * 100)
    assert main(["info", str(other)]) == 1
    _one_error_line(capsys)
    assert main(["info", str(tmp_path / "missing.DZT")]) == 1
    _one_error_line(capsys, "check the path")


def test_bad_config_key_is_one_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("survey:\n  spacing: 0.1\n")
    assert main(["demo", "--offline", "--config", str(bad), "--out", str(tmp_path / "run")]) == 1
    _one_error_line(capsys, "survey.spacing", "unknown key")


def test_demo_json_is_the_only_thing_on_stdout(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    small = tmp_path / "small.yaml"
    small.write_text("survey:\n  lines: 2\n  length_m: 0.8\nsim:\n  poses: noise\n")  # seconds, not a minute
    assert main(["demo", "--offline", "--config", str(small), "--out", str(tmp_path / "run"), "--json"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    (scene,) = summary["scenes"]
    assert scene["scene"] == "paper_slab" and scene["lines"] == 2 and scene["out_dir"] == str(tmp_path / "run")
    assert isinstance(scene["within_bounds"], bool) and scene["matches"] and "truth" in scene["matches"][0]
    assert captured.err == ""  # no progress bar: stderr is not a terminal
