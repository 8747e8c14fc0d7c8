"""GSSI DZT as a Radargram, through the DZT module's public API (read_dzt, write_dzt, header_info)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gprbot.gpr.dzt import header_info, read_dzt, write_dzt
from gprbot.gpr.formats.radargram import Radargram, integer_counts, uniform_positions

DEFAULT_EPS_R = 6.0  # written when the source states no permittivity (DZT needs one)


def read_dzt_radargram(path: Path, *, channel: int = 0, allow_partial: bool = False) -> Radargram:
    """One channel of a DZT file; positions from its traces per metre (None when it is 0)."""
    dzt = read_dzt(path, allow_partial=allow_partial)
    h = dzt.header
    samples = dzt.as_float(channel)
    spm = h.traces_per_m
    positions = uniform_positions(samples.shape[0], 1.0 / spm) if spm > 0 else None
    info = header_info(h)
    info["channel"] = channel
    return Radargram(
        samples=samples, dt_ns=h.dt_ns, source_format="dzt", positions_m=positions, antenna=h.antenna.strip(),
        header=info, warnings=tuple(str(w) for w in getattr(dzt, "warnings", ())),
    )


def write_dzt_radargram(path: Path, rg: Radargram) -> tuple[list[Path], list[str]]:
    """Write `rg` as a 16-bit DZT; integral samples are stored exactly, others scaled to full scale."""
    notes: list[str] = []
    counts, scale = integer_counts(rg.samples, 16)
    if scale != 1.0:
        notes.append(f"samples scaled by {scale:.6g} to 16-bit counts (DZT has no field for the scale)")
    step = rg.spacing_m()
    if rg.positions_m is not None and step:
        uniform = uniform_positions(rg.traces, step, float(rg.positions_m[0]))
        if float(np.abs(rg.positions_m - uniform).max()) > 0.01 * step + 1e-9:
            notes.append("trace positions are not evenly spaced: DZT keeps one spacing, the mean was written")
        if abs(rg.positions_m[0]) > 1e-9:
            notes.append(f"the first trace's position {rg.positions_m[0]:g} m is not kept (DZT starts at 0)")
    elif rg.positions_m is None:
        notes.append("no trace positions: traces per metre 0 (time mode)")
    if rg.time_zero_ns is not None:
        notes.append("DZT has no time-zero field: time zero not kept")
    eps = rg.header.get("eps_r") if rg.source_format == "dzt" else None
    if not (isinstance(eps, float | int) and 1.0 <= eps <= 1000.0):
        eps = DEFAULT_EPS_R
        notes.append(f"no permittivity stated: eps_r {DEFAULT_EPS_R:g} written (a default)")
    if rg.frequency_mhz:
        antenna = f"{rg.frequency_mhz:g}MHz"
    else:
        antenna = rg.antenna if len(rg.antenna) <= 14 and rg.antenna.isascii() else ""
    sps = rg.header.get("traces_per_s")
    sps = float(sps) if isinstance(sps, float | int) and 0 <= sps < 1e6 else 0.0
    stored = (counts + 32768).astype(np.uint16).T
    write_dzt(path, stored, range_ns=rg.window_ns, bits=16, traces_per_m=1.0 / step if step else 0.0,
              traces_per_s=sps, eps_r=float(eps), antenna=antenna)
    return [path], notes
