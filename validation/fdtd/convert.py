"""Finished gprMax B-scans → DZT (gprbot's own writer, 32-bit) + truth JSON + the committed .in file."""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import DataFormatError
from gprbot.gpr.dzt import write_dzt
from validation.fdtd.gprmax_input import in_sha256, input_text, layout
from validation.fdtd.scenes import Scene

HERE = Path(__file__).resolve().parent
DATA, INPUTS, WORK = HERE / "data", HERE / "inputs", HERE / "work"
MEDIUM_OFFSET = 54  # byte offset of rhf_epsr in the 1024-byte DZT header
SAMPLES_PER_PERIOD = 40  # the DZT's sample interval: 1 / (40 f_c), well above Nyquist for the Ricker band
TRUTH_KEYS = ("name", "half", "kind", "frequency_mhz", "eps_r", "conductivity_s_per_m", "velocity_m_per_ns",
              "antenna", "dt_ns", "source_peak_ns", "trace_x_m", "pipes", "rebars", "slab_bottom_m", "grid_m",
              "gprmax_version", "in_sha256")


def decimation(dt_ns: float, frequency_mhz: float) -> int:
    """The integer factor that brings the FDTD time step near 1 / (40 f_c)."""
    return max(1, int(1000.0 / (SAMPLES_PER_PERIOD * frequency_mhz) / dt_ns))


def resample(ez: NDArray[np.float64], factor: int) -> NDArray[np.float64]:
    """(traces, iterations) → (traces, samples), zero-phase low-pass and decimation; sample 0 stays at t = 0."""
    if factor == 1:
        return ez
    from scipy.signal import resample_poly

    return np.asarray(resample_poly(ez, 1, factor, axis=1))


def truth(scene: Scene, dt_ns: float, version: str) -> dict[str, Any]:
    """The truth record of a scene (SI metres, ns; x in the trace frame, depth below the surface)."""
    lay = layout(scene)
    eps = scene.concrete.eps_at(scene.frequency_mhz)
    return {
        "name": scene.name,
        "half": scene.half,
        "kind": scene.kind,
        "frequency_mhz": scene.frequency_mhz,
        "eps_r": round(eps, 4),
        "conductivity_s_per_m": scene.concrete.sigma_s_per_m,
        "velocity_m_per_ns": round(scene.velocity_m_per_ns(), 6),
        "antenna": {"model": "hertzian_dipole", "height_m": round(lay.height_m, 6),
                    "tx_rx_offset_m": round(lay.offset_m, 6)},
        "dt_ns": dt_ns,
        "source_peak_ns": round(lay.source_peak_ns, 6),
        "trace_x_m": [round(i * scene.step_m, 6) for i in range(scene.traces)],
        "pipes": [{"x_m": p.x_m, "depth_m": p.depth_m, "radius_m": p.radius_m, "fill": p.fill, "wall_m": p.wall_m}
                  for p in scene.pipes],
        "rebars": [{"x_m": r.x_m, "depth_m": r.depth_m, "radius_m": r.radius_m} for r in scene.rebars],
        "slab_bottom_m": scene.slab_bottom_m,
        "grid_m": lay.dx_m,
        "gprmax_version": version,
        "in_sha256": in_sha256(input_text(scene)),
    }


def _write_dzt(path: Path, data: NDArray[np.float64], range_ns: float, scene: Scene) -> None:
    """Write the DZT with eps_r 0 ("not set": the interpreter must find the velocity itself).

    gprbot's writer refuses eps_r < 1 while its reader takes 0 as "not set" (old GSSI units write 0), so
    when the writer refuses, the file is written with 1 and the rhf_epsr and rhf_depth fields are zeroed.
    """
    kwargs = {"range_ns": range_ns, "bits": 32, "traces_per_m": 1.0 / scene.step_m,
              "antenna": f"{round(scene.frequency_mhz)}MHz", "position_ns": 0.0}
    try:
        write_dzt(path, data, eps_r=0.0, **kwargs)  # type: ignore[arg-type]
    except DataFormatError:
        write_dzt(path, data, eps_r=1.0, **kwargs)  # type: ignore[arg-type]
        raw = bytearray(path.read_bytes())
        struct.pack_into("<fff", raw, MEDIUM_OFFSET, 0.0, 0.0, 0.0)  # rhf_epsr, rhf_top, rhf_depth
        path.write_bytes(bytes(raw))


def export(scene: Scene, ez: NDArray[np.float64], dt_s: float, version: str) -> Path:
    """Write data/<name>.DZT, data/<name>.json and inputs/<name>.in from a merged (traces, iterations) Ez array."""
    DATA.mkdir(parents=True, exist_ok=True)
    INPUTS.mkdir(parents=True, exist_ok=True)
    if ez.shape[0] != scene.traces:
        raise ValueError(f"{scene.name}: {ez.shape[0]} traces in the output, the scene has {scene.traces}")
    factor = decimation(dt_s * 1e9, scene.frequency_mhz)
    data = resample(np.asarray(ez, dtype=np.float64), factor)
    dt_ns = dt_s * 1e9 * factor
    samples = data.shape[1]
    dzt = DATA / f"{scene.name}.DZT"
    _write_dzt(dzt, data.T, samples * dt_ns, scene)
    record = truth(scene, round(dt_ns, 9), version)
    (INPUTS / f"{scene.name}.in").write_text(input_text(scene))
    tmp = DATA / f".{scene.name}.json.tmp"
    tmp.write_text(json.dumps(record, indent=1) + "\n")
    tmp.replace(DATA / f"{scene.name}.json")
    return dzt


def is_exported(scene: Scene) -> bool:
    """Whether data/ holds this scene's DZT and a truth JSON made from the current .in text."""
    path = DATA / f"{scene.name}.json"
    if not (path.exists() and (DATA / f"{scene.name}.DZT").exists()):
        return False
    try:
        return bool(json.loads(path.read_text()).get("in_sha256") == in_sha256(input_text(scene)))
    except (OSError, ValueError):
        return False


def apex_time_ns(record: dict[str, Any], x_m: float, depth_top_m: float) -> float:
    """Straight-ray two-way time from the trace nearest x to a point at depth_top_m below x (refraction ignored)."""
    h, off, v = record["antenna"]["height_m"], record["antenna"]["tx_rx_offset_m"], record["velocity_m_per_ns"]
    c = 0.299792458
    return float(record["source_peak_ns"] + 2.0 * (h / c) + 2.0 * math.hypot(depth_top_m, off / 2) / v)
