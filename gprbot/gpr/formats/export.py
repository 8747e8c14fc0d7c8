"""Every survey line of a run exported as line-NN.DZT, line-NN.DT1/.HD and line-NN-poses.csv.

The samples are the raw traces as recorded (before any preprocessing). The distance along the line
(the B-scan's along-track coordinate) goes into the DT1 trace headers exactly and into the DZT as its
mean traces per metre; the CSV gives each trace's time and antenna midpoint (site frame, metres).
The robot surveys without rotating (heading hold), and a B-scan keeps no orientation, so none is written.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from gprbot.gpr.bscan import BScan
from gprbot.gpr.formats.dt1 import write_dt1
from gprbot.gpr.formats.dzt_io import write_dzt_radargram
from gprbot.gpr.formats.radargram import Radargram, write_atomically

POSES_HEADER = "trace,time_s,along_m,x_m,y_m,z_m"


def line_radargram(bscan: BScan, gpr: Mapping[str, Any] | None = None) -> Radargram:
    """One raw survey line as a Radargram: along-track positions, time zero, the GPR's frequency and offset."""
    cfg = gpr or {}
    freq = cfg.get("centre_frequency_mhz")
    sep = cfg.get("tx_rx_offset_m")
    steps = np.diff(bscan.times)
    rate = 1.0 / float(np.median(steps)) if len(steps) and np.median(steps) > 0 else 0.0
    return Radargram(
        samples=np.asarray(bscan.data, dtype=np.float32), dt_ns=float(bscan.dt_ns), source_format="gprbot",
        positions_m=bscan.along_track_m(), time_zero_ns=float(bscan.t0_ns) if math.isfinite(bscan.t0_ns) else None,
        frequency_mhz=float(freq) if freq else None, antenna_separation_m=None if sep is None else float(sep),
        header={"traces_per_s": rate},
    )


def write_poses_csv(path: Path, bscan: BScan) -> None:
    """Per-trace index, time (s), distance along the line (m) and antenna midpoint x, y, z (m)."""
    table = np.column_stack([np.arange(len(bscan.times)), bscan.times, bscan.along_track_m(), bscan.positions])
    lines = [POSES_HEADER] + [f"{int(r[0])},{r[1]:.6f},{r[2]:.4f},{r[3]:.4f},{r[4]:.4f},{r[5]:.4f}" for r in table]

    def fill(f: BinaryIO) -> None:
        f.write(("\n".join(lines) + "\n").encode("ascii"))

    write_atomically(path, fill)


def export_survey_lines(out_dir: Path, lines: Mapping[int, BScan], gpr: Mapping[str, Any] | None = None) -> list[Path]:
    """Write every line's DZT, DT1 + HD and pose CSV into out_dir; returns the files written."""
    written: list[Path] = []
    for line, bscan in sorted(lines.items()):
        stem = out_dir / f"line-{line:02d}"
        rg = line_radargram(bscan, gpr)
        written += write_dzt_radargram(stem.with_suffix(".DZT"), rg)[0]
        written += write_dt1(stem, rg)[0]
        csv = out_dir / f"line-{line:02d}-poses.csv"
        write_poses_csv(csv, bscan)
        written.append(csv)
    return written
