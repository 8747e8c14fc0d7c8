"""Pictures as a GPR analyst reads them: site-frame x (backward lines as on the map), aspect, notes, progress."""

from __future__ import annotations

import io
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gprbot import progress
from gprbot.cli import main
from gprbot.config import GprConfig
from gprbot.gpr.bscan import BScan, SyntheticTarget, synthetic_bscan
from gprbot.gpr.render import bscan_image, display_clip, processing_note, vertical_exaggeration, write_bscan_png

GPR = GprConfig()


def _line(target_along_m: float) -> BScan:
    return synthetic_bscan(
        [SyntheticTarget(target_along_m, 0.15, 0.03, amplitude=-1.0)], v_m_per_ns=0.12, centre_frequency_mhz=900.0,
        n_traces=150, spacing_m=0.01, samples=256, dt_ns=GPR.dt_ns, t0_ns=GPR.pre_trigger_ns,
        antenna_height_m=0.02, tx_rx_offset_m=0.05, rng=np.random.default_rng(3),
    )


def _apex_site_x(bscan: BScan) -> float:
    _, grid, data = bscan_image(bscan)
    return float(grid[np.argmax(np.abs(data[40:]).max(axis=0))])  # below the direct wave


def test_a_backward_line_is_drawn_in_site_x_like_the_map() -> None:
    forward = _line(0.45)
    positions = forward.positions.copy()
    positions[:, 0] = 2.0 - positions[:, 0]  # the robot drove from x = 2.0 towards x = 0.51
    backward = replace(forward, positions=positions)
    assert _apex_site_x(forward) == pytest.approx(0.45, abs=0.015)
    assert _apex_site_x(backward) == pytest.approx(1.55, abs=0.015)  # not 0.45 ("distance from the first trace")
    axis, grid, _ = bscan_image(backward)
    assert axis.sign == -1 and axis.name == "x" and "←" in axis.label and np.all(np.diff(grid) > 0)


def test_a_sideways_line_is_drawn_along_site_y() -> None:
    line = _line(0.3)
    positions = np.column_stack([np.full(len(line.positions), 0.7), line.positions[:, 0] + 0.2,
                                 np.zeros(len(line.positions))])
    axis, _, _ = bscan_image(replace(line, positions=positions))
    assert axis.name == "y" and axis.sign == 1 and float(axis.of(0.3)) == pytest.approx(0.5)


def test_section_grey_scale_is_not_set_by_the_surface_row_or_the_migration_edge() -> None:
    picture = np.full((200, 300), 0.01)
    picture[90:105, 130:170] = 1.0  # a target's focus (1 % of the cells)
    picture[:3] = 50.0  # the direct wave's residue
    picture[-4:] = 80.0  # migration's edge
    assert display_clip(picture) == pytest.approx(1.0)


def test_vertical_exaggeration_is_a_stated_round_factor() -> None:
    assert vertical_exaggeration(2.0, 0.6) == 1.0  # the demo's 2 m line at 0.6 m: true scale
    assert vertical_exaggeration(20.0, 2.9) == 2.0  # the 20 m × 2.9 m section of the issue (was ~10×, unsaid)
    assert vertical_exaggeration(40.0, 0.5) == 50.0


def test_processing_note_names_every_step() -> None:
    note = processing_note(("dewow", "direct:-1", "background", "gain:1.0:50.0"))
    assert note == "dewow, background removed, gain t^1 (cap 50×)"
    assert processing_note(()) == "raw (no processing)"


def test_bscan_png_with_a_depth_axis_is_written(tmp_path: Path) -> None:
    write_bscan_png(tmp_path / "b.png", _line(0.45), 0.12, "given", title="test")
    assert (tmp_path / "b.png").read_bytes()[:4] == b"\x89PNG" and not list(tmp_path.glob(".*.tmp"))


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bars_only_on_a_terminal_and_not_when_quiet(monkeypatch: pytest.MonkeyPatch) -> None:
    assert not progress.enabled()  # pytest captures stderr: not a terminal
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    assert progress.enabled()
    with progress.bar(3, "lines") as bar:
        bar.update(3)
    assert "lines" in terminal.getvalue() and "/3" in terminal.getvalue()
    progress.set_quiet(True)
    try:
        assert not progress.enabled()
    finally:
        progress.set_quiet(False)


def test_config_check(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = tmp_path / "good.yaml"
    good.write_text("survey:\n  lines: 4\nretention:\n  max_runs: 20\n")
    assert main(["config", "check", str(good)]) == 0
    assert "ok" in capsys.readouterr().out
    assert main(["config", "check", str(good), "--json"]) == 0
    assert '"max_runs": 20' in capsys.readouterr().out
    bad = tmp_path / "bad.yaml"
    bad.write_text("georeference:\n  origin_lat_deg: 47.0\n")
    assert main(["config", "check", str(bad)]) == 1
    assert "origin_lon_deg" in capsys.readouterr().err
    with pytest.raises(SystemExit) as usage:
        main(["config", "check"])
    assert usage.value.code == 2


def test_interpret_draws_the_bscan_at_the_chains_time_zero() -> None:
    from gprbot.apps.interpret_file import shown_bscan

    raw = replace(_line(0.45), t0_ns=float("nan"))  # a file without time zero: the chain estimates it
    shown = shown_bscan(raw, GPR, 0.61)
    assert shown.t0_ns == 0.61  # before: preprocess estimated time zero a second time (0.73 ns on File____002)


def test_under_systemd_matplotlib_caches_in_the_state_directory(tmp_path: Path) -> None:
    import os
    import subprocess

    env = {k: v for k, v in os.environ.items() if k != "MPLCONFIGDIR"}
    env |= {"HOME": str(tmp_path / "no-home"), "STATE_DIRECTORY": str(tmp_path / "state"), "XDG_CONFIG_HOME": ""}
    (tmp_path / "no-home").mkdir(mode=0o500)  # ProtectHome: nothing writable there
    done = subprocess.run([sys.executable, "-c", "import os, gprbot.plotting; print(os.environ['MPLCONFIGDIR'])"],
                          env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == str(tmp_path / "state" / "matplotlib")
    assert "temporary cache directory" not in done.stderr
