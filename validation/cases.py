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


def _file_loader(path: Path, spacing_m: float | None = None,
                 frequency_mhz: float | None = None) -> Callable[[], tuple[BScan, GprConfig]]:
    """Read any file exactly as `gprbot interpret FILE [--spacing] [--frequency]` does."""
    def load() -> tuple[BScan, GprConfig]:
        from gprbot.apps.interpret_file import file_bscan, gpr_config_for

        bscan, rg = file_bscan(path, 0, spacing_m)
        return bscan, gpr_config_for(rg, GprConfig(), frequency_mhz)
    return load


SU_TRACE_M, SU_DT_NS, SU_FILL_V = 0.04006, 0.09766, 0.165  # the file's d2 and d1; the sand fill's velocity
SU_APEXES = ((210, 270), (205, 400), (370, 255), (410, 260), (450, 170), (470, 195), (510, 110))  # its README


def _su_apexes() -> tuple[Target, ...]:
    """The trench line's apexes as its README reads them (trace, raw sample), in metres (depth at the fill's v)."""
    return tuple(Target(trace * SU_TRACE_M, 0.5 * SU_FILL_V * sample * SU_DT_NS, None, "pipe")
                 for trace, sample in SU_APEXES)


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
        Case("gprMax 2D PEC bar (3.1.7 .out)", "real", _file_loader(REAL_DATA / "gprmax_cylinder_2d" /
                                                               "cylinder_Bscan_2D_merged.out"),
             6 ** -0.5 * 0.299792458, (Target(0.06, 0.09, 0.01, "pipe"),), 0.03,
             note="exact: r 10 mm, 90 mm to the centre, eps_r 6; only 60 traces (12 cm) at 2 mm"),
        Case("gprMax 3D GSSI-1.5 GHz antenna model, PEC bar", "real",
             _file_loader(REAL_DATA / "gprmax_gssi1500_cylinder_3d" / "GSSI_1500_cylinder_Bscan_all.out", 0.005),
             6 ** -0.5 * 0.299792458, (Target(0.135, 0.09, 0.01, "pipe"),), 0.03,
             note="exact geometry; positions from the .in's python block (--spacing 0.005); the model's Tx-Rx "
                  "separation is not stated, the antenna table's 5 cm is used"),
        Case("SU trench with 12 diffractors", "real",
             _file_loader(REAL_DATA / "su_trench_pipes_matgpr" / "trench_and_pipes.su", None, 500.0),
             None, _su_apexes(), 0.2, expected_count=12,
             note="12 diffractors published, positions not: scored against the 7 apexes its README reads off "
                  "the image ((trace, sample), by eye), at 0.165 m/ns (the fill's published velocity), ±0.2 m; "
                  "dt and trace step inferred; the file states no frequency: 500 MHz is passed"),
        Case("MALÅ RD3 250 MHz geology (negative)", "real",
             _file_loader(REAL_DATA / "mala_rd3_250mhz_matgpr" / "DAT_0097.rd3"), None, (), 0.03, expected_count=0,
             note="dipping geology, no buried objects: a good interpretation reports none"),
        Case("pulseEKKO DT1 100 MHz sediments (negative)", "real",
             _file_loader(REAL_DATA / "pulseekko_dt1_rgpr_negative" / "yyline3.DT1"), None, (), 0.03, expected_count=0,
             note="fluvial sediments, no point targets"),
        Case("SIR-3000 400 MHz field line FILE____032 (no truth)", "real",
             _file_loader(REAL_DATA / "FILE____032.DZT"), None, (), 0.03, expected_count=None,
             note="no buried-object truth; no clean subsurface hyperbola is visible (reported, not scored)"),
    ]
    return cases
