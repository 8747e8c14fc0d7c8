"""What `gprbot info` shows for a Radargram: a JSON-ready dict and a human-readable table."""

from __future__ import annotations

from typing import Any

import numpy as np

from gprbot.gpr.formats.radargram import Radargram

FORMAT_NAMES = {
    "dzt": "GSSI DZT", "dt1": "Sensors & Software DT1 + HD", "mala": "MALÅ RD3/RD7 + RAD",
    "segy": "SEG-Y", "su": "Seismic Unix (SU)", "gprmax": "gprMax output (HDF5)",
}


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def radargram_info(rg: Radargram) -> dict[str, Any]:
    """The Radargram's facts as plain JSON-ready values, for `gprbot info --json`."""
    pos = rg.positions_m
    info: dict[str, Any] = _jsonable({
        "format": rg.source_format,
        "format_name": FORMAT_NAMES.get(rg.source_format, rg.source_format),
        "traces": rg.traces,
        "samples": rg.n_samples,
        "dt_ns": rg.dt_ns,
        "window_ns": rg.window_ns,
        "time_zero_ns": rg.time_zero_ns,
        "positions_m": None if pos is None else {"first": pos[0], "last": pos[-1], "mean_step": rg.spacing_m()},
        "frequency_mhz": rg.frequency_mhz,
        "antenna_separation_m": rg.antenna_separation_m,
        "antenna": rg.antenna,
        "gps_traces": None if rg.geo is None else int(np.isfinite(rg.geo[:, 0]).sum()),
        "amplitude": {"min": float(rg.samples.min()), "max": float(rg.samples.max())},
        "warnings": list(rg.warnings),
        "header": rg.header,
    })
    return info


def format_radargram_info(rg: Radargram) -> str:
    """A human-readable table of a Radargram, as `gprbot info` prints it for non-DZT files."""
    pos = rg.positions_m
    step = rg.spacing_m()
    rows = [
        ("format", FORMAT_NAMES.get(rg.source_format, rg.source_format)),
        ("traces", str(rg.traces)),
        ("samples", f"{rg.n_samples} per trace"),
        ("time window", f"{rg.window_ns:g} ns (dt {rg.dt_ns:.5g} ns)"),
        ("time zero", "not stated" if rg.time_zero_ns is None else f"{rg.time_zero_ns:g} ns after sample 0"),
        ("positions", "none (no distance calibration)" if pos is None
         else f"{pos[0]:g} .. {pos[-1]:g} m" + (f" (step {step:.4g} m)" if step else "")),
        ("antenna", rg.antenna or "not stated"),
        ("frequency", "not stated" if rg.frequency_mhz is None else f"{rg.frequency_mhz:g} MHz"),
        ("Tx-Rx separation", "not stated" if rg.antenna_separation_m is None else f"{rg.antenna_separation_m:g} m"),
        ("amplitude", f"{float(rg.samples.min()):.6g} .. {float(rg.samples.max()):.6g}"),
    ]
    if rg.geo is not None:
        rows.append(("GPS", f"{int(np.isfinite(rg.geo[:, 0]).sum())} traces with a fix"))
    width = max(len(name) for name, _ in rows)
    lines = [f"{name:<{width}}  {value}" for name, value in rows]
    lines += [f"warning: {w}" for w in rg.warnings]
    return "\n".join(lines)
