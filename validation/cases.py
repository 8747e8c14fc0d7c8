"""The yardsticks as cases: FDTD scenes (validation/fdtd/data, truth exact) and real files (truth per README).

A case is a B-scan as a user's reader gives it (positions from the file's own trace spacing), the
antenna geometry a user would configure, the velocity when it is known, and the targets to score.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from gprbot.config import GprConfig
from gprbot.gpr.bscan import BScan
from gprbot.gpr.dzt import read_dzt
from validation.scoring import Target

FDTD_DATA = Path(__file__).resolve().parent / "fdtd" / "data"
REAL_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


@dataclass(frozen=True)
class Case:
    """One B-scan to interpret and what is known about it."""

    name: str
    group: str  # "fdtd-dev", "fdtd-test", "real"
    load: Callable[[], tuple[BScan, GprConfig]]
    velocity: float | None  # the true velocity, when known
    targets: tuple[Target, ...]
    tolerance_m: float
    expected_count: int | None = None  # when only a count is known (positions unpublished)
    note: str = ""


def bscan_along_x(data: np.ndarray, dt_ns: float, spacing_m: float) -> BScan:
    """Traces at `spacing_m` along x, time zero unknown (found from the direct wave)."""
    n = data.shape[0]
    positions = np.zeros((n, 3))
    positions[:, 0] = np.arange(n) * spacing_m
    return BScan(np.asarray(data, dtype=np.float32), dt_ns, math.nan, positions, np.zeros(n))


def _gpr(frequency_mhz: float, height_m: float, offset_m: float) -> GprConfig:
    """The antenna as a user configures it."""
    return replace(GprConfig(), centre_frequency_mhz=frequency_mhz, antenna_height_m=height_m,
                   tx_rx_offset_m=offset_m, eps_r=None)


def _dzt_loader(path: Path, frequency_mhz: float, height_m: float, offset_m: float,
                spacing_m: float | None = None) -> Callable[[], tuple[BScan, GprConfig]]:
    """Read a DZT with a known antenna (the FDTD scenes: the truth's geometry, as a user configures it)."""
    def load() -> tuple[BScan, GprConfig]:
        dzt = read_dzt(path)
        spacing = spacing_m or 1.0 / dzt.header.traces_per_m
        return bscan_along_x(dzt.as_float(), dzt.header.dt_ns, spacing), _gpr(frequency_mhz, height_m, offset_m)
    return load


def _file_loader(path: Path) -> Callable[[], tuple[BScan, GprConfig]]:
    """Read any file exactly as `gprbot interpret FILE` does (geometry from the file or the antenna table)."""
    def load() -> tuple[BScan, GprConfig]:
        from gprbot.interpret_file import file_bscan, gpr_config_for

        bscan, rg = file_bscan(path, 0, None)
        return bscan, gpr_config_for(rg, GprConfig(), None)
    return load


def fdtd_cases() -> list[Case]:
    """Every finished FDTD scene, with its half."""
    out = []
    for truth_path in sorted(FDTD_DATA.glob("*.json")):
        t = json.loads(truth_path.read_text())
        dzt = truth_path.with_suffix(".DZT")
        if not dzt.exists():
            continue
        ant = t["antenna"]
        targets = tuple(Target(p["x_m"], p["depth_m"], p["radius_m"], "pipe") for p in t["pipes"])
        targets += tuple(Target(b["x_m"], b["depth_m"], b["radius_m"], "rebar") for b in t["rebars"])
        out.append(Case(t["name"], f"fdtd-{t['half']}",
                        _dzt_loader(dzt, float(t["frequency_mhz"]), ant["height_m"], ant["tx_rx_offset_m"]),
                        float(t["velocity_m_per_ns"]), targets, 0.03, note=t["kind"]))
    return out


def real_cases() -> list[Case]:
    """The real files whose READMEs give targets (positions, or a count), and the negative controls."""
    ss = REAL_DATA / "gssi_ssmini_rebar_ietgpr"
    bars_002 = (0.08, 0.30, 0.48, 0.69, 0.88, 1.11, 1.30)
    cases = [
        Case("ssmini File____002 (7 rebars)", "real", _file_loader(ss / "File____002.DZT"),
             None, tuple(Target(x, None, None, "rebar") for x in bars_002), 0.02,
             note="positions read from the data by eye, ±2 cm"),
        Case("ssmini File____001 (3 shallow + 2 deeper)", "real",
             _file_loader(ss / "File____001.DZT"), None,
             tuple(Target(x, None, None, "rebar") for x in (0.165, 0.49, 0.81))
             + tuple(Target(x, None, None, "pipe") for x in (0.23, 0.56)), 0.03,
             note="medium trust; the deeper row's kind is unknown (scored as targets of any kind)"),
    ]
    return cases
