"""`gprbot interpret`: one B-scan from any GPR file (DZT, DT1, RD3, SEG-Y, SU, gprMax) → detections.json and PNGs."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from gprbot.config import GprConfig, InterpretationConfig, load_config
from gprbot.errors import DataFormatError, InterpretationError
from gprbot.gpr.antennas import GSSI_ANTENNAS, antenna_frequency_mhz, check_frequency_mhz
from gprbot.gpr.bscan import BScan
from gprbot.gpr.formats import Radargram, read_radargram
from gprbot.gpr.interpret import interpret_bscan
from gprbot.gpr.preprocess import preprocess
from gprbot.gpr.render import write_bscan_png, write_cross_section_png
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.infer.outputs import write_json_atomic

__all__ = [
    "GSSI_ANTENNAS", "antenna_frequency_mhz", "file_bscan", "gpr_config_for", "interpret_dzt", "interpret_file",
    "radargram_bscan",
]

# A GSSI ground-coupled antenna rides on the surface; its Tx–Rx spacing is a fraction of a
# wavelength in air. These are approximations for the travel-time model, not vendor figures.
DEFAULT_OFFSET_M = {100: 0.5, 200: 0.3, 270: 0.25, 400: 0.16, 500: 0.12, 900: 0.06}


def gpr_config_for(rg: Radargram, base: GprConfig, frequency_mhz: float | None) -> GprConfig:
    """The acquisition settings of a file expressed as a GprConfig (frequency from the file or its antenna name)."""
    if frequency_mhz is not None and (problem := check_frequency_mhz(frequency_mhz)) is not None:
        raise DataFormatError(f"--frequency: {problem}; give the antenna's centre frequency in MHz")
    mhz = frequency_mhz or rg.frequency_mhz or antenna_frequency_mhz(rg.antenna)
    if mhz is None:
        raise DataFormatError(
            f"cannot tell the antenna's centre frequency from the file (antenna {rg.antenna!r}); pass --frequency MHZ"
        )
    offset = rg.antenna_separation_m
    if offset is None:
        offset = next((v for f, v in sorted(DEFAULT_OFFSET_M.items()) if mhz <= f), 0.05)
    return replace(
        base,
        centre_frequency_mhz=mhz,
        samples=rg.n_samples,
        time_window_ns=rg.window_ns,
        pre_trigger_ns=float("nan") if rg.time_zero_ns is None else rg.time_zero_ns,
        antenna_height_m=0.0,
        tx_rx_offset_m=offset,
        eps_r=None,
    )


def radargram_bscan(rg: Radargram, spacing_m: float | None, source: str = "the file") -> BScan:
    """A Radargram as a B-scan along x: positions from the file, or `spacing_m` apart when given."""
    if rg.traces == 0:
        raise DataFormatError(f"{source}: the file holds no traces")
    n = rg.traces
    positions = np.zeros((n, 3))
    if spacing_m:
        positions[:, 0] = np.arange(n) * spacing_m
    elif rg.positions_m is not None:
        positions[:, 0] = rg.positions_m - rg.positions_m[0]
    else:
        raise DataFormatError(f"{source}: the file has no distance calibration; pass --spacing M")
    t0 = float("nan") if rg.time_zero_ns is None else rg.time_zero_ns
    return BScan(rg.samples, rg.dt_ns, t0, positions, np.zeros(n))


def file_bscan(
    path: Path, channel: int, spacing_m: float | None, allow_partial: bool = False
) -> tuple[BScan, Radargram]:
    """The traces of one channel of any GPR file as a B-scan along x, with the file's Radargram."""
    rg = read_radargram(path, channel=channel, allow_partial=allow_partial)
    return radargram_bscan(rg, spacing_m, str(path)), rg


def interpret_file(
    path: Path,
    out_dir: Path | None,
    velocity: float | None,
    channel: int = 0,
    frequency_mhz: float | None = None,
    spacing_m: float | None = None,
    allow_partial: bool = False,
) -> str:
    """Interpret a GPR file of any format, write detections.json and PNGs, and return a printable report."""
    cfg = load_config()
    bscan, rg = file_bscan(path, channel, spacing_m, allow_partial)
    notes: list[str] = list(rg.warnings)
    gpr = gpr_config_for(rg, cfg.gpr, frequency_mhz)
    eps_r = float(rg.header.get("eps_r") or 0.0) if rg.source_format == "dzt" else 0.0
    interp: InterpretationConfig = cfg.interpretation
    out = out_dir or Path(cfg.runs_dir) / time.strftime(f"interpret-{path.stem}-%Y%m%d-%H%M%S")
    out.mkdir(parents=True, exist_ok=True)
    # The time window sets how deep the section can reach; the 0.6 m default suits a slab at 900 MHz.
    v_guess = velocity or velocity_from_eps(eps_r if eps_r > 1 else 6.0)
    interp = replace(interp, depth_max_m=0.5 * v_guess * rg.window_ns)
    processed = preprocess(bscan, gpr)
    try:
        section = interpret_bscan(processed, gpr, interp, velocity)
    except InterpretationError as exc:
        if velocity is not None or eps_r <= 1:
            raise
        # No hyperbola to measure the velocity on: fall back to the permittivity the operator set.
        notes.append(f"velocity not estimated ({exc}); used the header's eps_r {eps_r:g}")
        section = interpret_bscan(processed, gpr, interp, velocity_from_eps(eps_r))
    detections = [
        {"x_m": d.x_m, "depth_m": d.depth_m, "radius_m": d.radius_m, "score": d.score} for d in section.detections
    ]
    write_json_atomic(
        out / "detections.json",
        {
            "file": str(path),
            "channel": channel,
            "format": rg.source_format,
            "antenna": rg.antenna,
            "centre_frequency_mhz": gpr.centre_frequency_mhz,
            "velocity_m_per_ns": section.velocity_m_per_ns,
            "velocity_estimated": section.velocity_estimated,
            "x_origin": "the first trace",
            "depth_origin": "the ground surface (depth of the pipe's centre, positive down)",
            "detections": detections,
            "notes": notes,
        },
    )
    write_bscan_png(out / "bscan.png", processed)
    write_cross_section_png(out / "section.png", section)
    lines = [
        f"{path.name} ({rg.source_format}): {rg.traces} traces × {rg.n_samples} samples, "
        f"{gpr.centre_frequency_mhz:.0f} MHz",
        f"velocity {section.velocity_m_per_ns:.4f} m/ns "
        f"({'estimated' if section.velocity_estimated else 'given'}), {len(detections)} detections:",
    ]
    lines += [
        f"  x {d['x_m']:6.2f} m  depth {d['depth_m']:5.2f} m  radius {100 * d['radius_m']:4.1f} cm  "
        f"score {d['score']:.2f}"
        for d in detections
    ]
    lines += [f"note: {n}" for n in notes]
    lines.append(f"written: {out}/detections.json, bscan.png, section.png")
    return "\n".join(lines)


interpret_dzt = interpret_file  # the name before other formats were read
