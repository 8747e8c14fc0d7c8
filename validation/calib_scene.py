"""An FDTD truth record → the same scene for gprbot's simulator, and our B-scan on the FDTD's time axis.

The FDTD scenes are 2D cross-sections: every pipe and bar crosses the line at 90°, so each becomes a
straight pipe along y, long enough (±1 m) that its ends never show. The line runs along x at y = 0 with
the trace midpoints of the truth record. Time: FDTD sample k lies at k·dt after the source *start*, and the
source peaks at `source_peak_ns`; our sample k lies at k·dt − pre_trigger after the transmit instant (the
wavelet's peak), so pre_trigger = source_peak_ns puts both on one axis.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.config import GprConfig
from gprbot.gpr.dzt import read_dzt
from gprbot.sim.forward import receiver_drift, simulate_bscan
from gprbot.sim.scene import Pipe, Scene, Slab
from gprbot.sim.variation import SignalVariation
from validation.calib_measure import direct_window_ns, wavelet_corr

FDTD_DATA = Path(__file__).resolve().parent / "fdtd" / "data"
HALF_LENGTH_M = 1.0  # pipes run from y = -1 m to +1 m: their end diffractions fall far outside the window
HALF_SPACE_M = 20.0  # no slab bottom in the FDTD scene: ours lies far beyond the time window
ETA0 = 376.730313668
EPS0 = 8.8541878128e-12


def scene_names() -> list[str]:
    """Names of the FDTD scenes with both a DZT and a truth JSON."""
    return sorted(p.stem for p in FDTD_DATA.glob("*.json") if p.with_suffix(".DZT").exists())


def load_fdtd(name: str, folder: Path = FDTD_DATA) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """The FDTD B-scan (traces, samples) as recorded and its truth record."""
    truth = json.loads((folder / f"{name}.json").read_text())
    data = read_dzt(folder / f"{name}.DZT").as_float().astype(np.float64)
    return data, truth


def stones_of(name: str) -> int:
    """How many aggregate grains the FDTD scene holds (not in the truth JSON; our scene has none)."""
    from validation.fdtd.scenes import all_scenes

    return next((len(s.stones) for s in all_scenes() if s.name == name), 0)


def below_of(name: str) -> str:
    """What lies under the FDTD scene's slab bottom ("air" or "soil")."""
    from validation.fdtd.scenes import all_scenes

    return next((s.below for s in all_scenes() if s.name == name), "air")


def loss_db_per_m(truth: dict[str, Any], debye: tuple[float, float] | None = None) -> float:
    """Plane-wave amplitude loss (dB/m) at the centre frequency from the conductivity (and a Debye pole)."""
    w = 2.0 * math.pi * truth["frequency_mhz"] * 1e6
    eps1 = float(truth["eps_r"])
    eps2 = truth["conductivity_s_per_m"] / (w * EPS0)
    if debye is not None:
        delta, tau = debye
        eps2 += delta * w * tau / (1.0 + (w * tau) ** 2)
    alpha = w / 299792458.0 * math.sqrt(eps1 / 2.0 * (math.sqrt(1.0 + (eps2 / eps1) ** 2) - 1.0))
    return 20.0 / math.log(10.0) * alpha


def debye_of(name: str) -> tuple[float, float] | None:
    """The FDTD scene's Debye pole (delta_eps, tau_s), None when the concrete is not dispersive."""
    from validation.fdtd.scenes import all_scenes

    return next((s.concrete.debye for s in all_scenes() if s.name == name), None)


FDTD_SOIL_EPS_R = 15.0  # the generator's "soil" (validation.fdtd.gprmax_input.EPS_SOIL)


def _below_eps_r(truth: dict[str, Any]) -> float:
    """What lies under the FDTD slab's bottom, as our slab's below_eps_r."""
    return 1.0 if below_of(truth["name"]) == "air" else FDTD_SOIL_EPS_R


def to_sim_scene(truth: dict[str, Any], debye: tuple[float, float] | None = None,
                 below_eps_r: float = 15.0) -> Scene:
    """Our scene: a slab under the line (over soil, or air: below_eps_r 1), each truth target a pipe along y."""
    xs = truth["trace_x_m"]
    x0, x1 = min(xs) - 1.0, max(xs) + 1.0
    thickness = truth["slab_bottom_m"] or HALF_SPACE_M
    slab = Slab((x1 - x0, 2.0 * HALF_LENGTH_M + 0.2), (x0, -HALF_LENGTH_M - 0.1), float(thickness),
                float(truth["eps_r"]), loss_db_per_m(truth, debye), below_eps_r)

    def pipe(name: str, x: float, depth: float, radius: float, fill: str) -> Pipe:
        points = np.array([[x, -HALF_LENGTH_M, -depth], [x, HALF_LENGTH_M, -depth]])
        return Pipe(name, points, radius, fill)  # type: ignore[arg-type]

    pipes = [pipe(f"pipe{i}", p["x_m"], p["depth_m"], p["radius_m"], p["fill"]) for i, p in enumerate(truth["pipes"])]
    pipes += [pipe(f"rebar{i}", b["x_m"], b["depth_m"], b["radius_m"], "metal") for i, b in enumerate(truth["rebars"])]
    return Scene(truth["name"], "from the FDTD truth record", slab, tuple(pipes), None, None)


def to_gpr_config(truth: dict[str, Any], samples: int) -> GprConfig:
    """Our antenna with the FDTD's frequency, height, offset and time axis; no noise."""
    ant = truth["antenna"]
    return replace(GprConfig(), centre_frequency_mhz=float(truth["frequency_mhz"]), samples=samples,
                   time_window_ns=samples * float(truth["dt_ns"]), pre_trigger_ns=float(truth["source_peak_ns"]),
                   antenna_height_m=float(ant["height_m"]), tx_rx_offset_m=float(ant["tx_rx_offset_m"]),
                   noise_mv=0.0, eps_r=float(truth["eps_r"]))


def render_ours(truth: dict[str, Any], samples: int, debye: tuple[float, float] | None = None,
                seed: int = 0, variation: SignalVariation | None = None) -> NDArray[np.float64]:
    """Our B-scan (traces, samples) in mV at the truth's trace midpoints, without the receiver's wow and noise.

    The wow is a receiver artefact the FDTD has no counterpart of; it is the first draw from the generator
    in `simulate_bscan`, so the same draw from a second generator of the same seed removes it exactly.
    A `variation` renders one point of the training data's domain randomisation instead of the default.
    """
    gpr = to_gpr_config(truth, samples)
    mid = np.zeros((len(truth["trace_x_m"]), 2))
    mid[:, 0] = truth["trace_x_m"]
    scene = to_sim_scene(truth, debye, _below_eps_r(truth))
    bscan = simulate_bscan(scene, mid, gpr, np.random.default_rng(seed), variation=variation).astype(np.float64)
    return bscan - receiver_drift(len(mid), gpr, np.random.default_rng(seed))


def picture(name: str, folder: Path) -> Path:
    """FDTD | ours (in the FDTD's polarity), mean trace removed, then both raw, side by side as a PNG."""
    import cv2

    fdtd, truth = load_fdtd(name)
    ours = render_ours(truth, fdtd.shape[1], debye_of(name))
    end = int(direct_window_ns(truth) / truth["dt_ns"])
    flip = wavelet_corr(np.median(fdtd, 0)[:end], np.median(ours, 0)[:end], 1)[0]
    ours = ours if flip >= 0 else -ours  # shown in the FDTD's polarity

    def img(b: np.ndarray, raw: bool) -> np.ndarray:
        b = b if raw else b - b.mean(0)
        b = b / (np.percentile(np.abs(b), 99.5) + 1e-12)
        g = np.clip(128 + 127 * b.T, 0, 255).astype(np.uint8)
        return cv2.resize(g, (g.shape[1] * 5, g.shape[0]), interpolation=cv2.INTER_NEAREST)

    panels = [img(fdtd, False), img(ours, False), img(fdtd, True), img(ours, True)]
    sep = np.full((panels[0].shape[0], 6), 255, np.uint8)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.png"
    cv2.imwrite(str(path), np.hstack([p for q in panels for p in (q, sep)]))
    return path
