"""The surveys training.eval_end_to_end runs every chain on: held-out simulated scenes, and FDTD B-scans.

A `Survey` is what a site visit leaves — raw B-scans with recorded positions and the antenna settings
(eps_r unknown) — plus the truth to score against: the scene's pipes, the surveyed rectangle and a dense
truth cloud in a unit cube that every chain is scored in.

FDTD surveys (`fdtd_surveys`): the gprMax scenes of validation/fdtd are 2D (TMz), every pipe crossing the
line at 90°. A straight pipe perpendicular to parallel survey lines has the same cross-section on every
line, so a survey of N lines over one FDTD scene is that scene's B-scan on every line, with the recorded
positions jittered by pose noise and the receiver noise drawn afresh per line (the files are noise-free);
its truth is the scene's pipes extruded across the lines. The line count, spacing, pose noise and noise
level are drawn as the random scenes draw them. Such a survey measures the chains on independent physics
— wavelet, ringing, PVC inner echoes, lossy and dispersive concrete, rebar — but only for straight pipes
perpendicular to the lines: no bends, tees, oblique crossings or missing lines.
"""

from __future__ import annotations

import functools
import json
import math
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.config import GprConfig
from gprbot.gpr.bscan import BScan
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.infer.gprnet import normalisation
from gprbot.motion.planner import survey_region as planned_region
from gprbot.sim.forward import simulate_bscan
from gprbot.sim.scene import Pipe, Scene, Slab
from gprbot.sim.truth import sample_pipe_interiors
from training.migration_data import simulate_line
from training.pointcloud_data import DENSE_POINTS, load_split
from training.random_scenes import SurveySpec, gpr_config, random_scene, recorded_positions, scene_for_seed
from validation.cases import FDTD_DATA, Case, fdtd_cases

Region = tuple[float, float, float, float]
_RNG_TAG = 0xE2E  # the simulated surveys' stream (as before this module: the same B-scans)
_FDTD_TAG = 0xFD7D
_TRACE_INTERVAL_S = 0.05
_SLAB_MARGIN_M = 0.3
# conductivity (S/m) → loss (dB/m) in a low-loss dielectric: alpha = 8.686 sigma eta0 / (2 sqrt(eps_r))
_DB_PER_M_PER_S_M = 8.686 * 376.73 / 2.0


@dataclass(frozen=True)
class Survey:
    """One survey's raw lines and antenna settings, and the truth it is scored against."""

    name: str
    case: str
    seed: int
    bscans: Mapping[int, BScan]
    gpr: GprConfig  # eps_r None: the chains estimate the velocity
    truth: Scene
    region: Region
    true_velocity: float
    # the truth cloud in the scoring unit cube, its centre and scale (metres); None when there is no pipe
    dense: NDArray[np.float32] | None
    centre: NDArray[np.float64]
    scale: float


def survey_region(spec: SurveySpec) -> Region:
    """The surveyed rectangle (xmin, xmax, ymin, ymax): lines ± half a spacing, as the dataset's truth."""
    half = 0.5 * spec.spacing_m
    return planned_region(spec.start_xy, spec.length_m, spec.lines, spec.spacing_m, across_margin_m=half)


def simulated_lines(seed: int, base: GprConfig) -> tuple[Scene, SurveySpec, dict[int, BScan], GprConfig]:
    """A random scene's survey simulated on every kept line (pose noise, clutter, rebar, missing lines as drawn),
    and the antenna settings to interpret it with (eps_r None)."""
    scene, spec = scene_for_seed(seed)
    rng = np.random.default_rng([seed, _RNG_TAG])
    bscans = {line: simulate_line(scene, spec, line, rng) for line in spec.kept_lines()}
    return scene, spec, bscans, replace(gpr_config(spec, scene, base), eps_r=None)


def simulated_survey(index: int, data: Mapping[str, NDArray[Any]], base: GprConfig) -> Survey:
    """Test sample `index` of the completion split: its survey simulated (simulated_lines), scored in the
    sample's unit cube (training's normalisation)."""
    seed = int(data["seed"][index])
    scene, spec, bscans, gpr = simulated_lines(seed, base)
    return Survey(f"seed {seed}", str(data["case"][index]), seed, bscans, gpr, scene, survey_region(spec),
                  velocity_from_eps(scene.slab.eps_r), np.asarray(data["dense"][index], dtype=np.float32),
                  np.asarray(data["centre"][index], dtype=np.float64), float(data["scale"][index]))


def survey_makers(source: str, gpr: GprConfig, limit: int = 60, half: str = "test") -> list[Callable[[], Survey]]:
    """Lazy makers of the surveys of one source: "sim" (the first `limit` test surveys, built one at a time, with
    the antenna settings of `gpr`) or "fdtd" (every scene of one FDTD half)."""
    if source == "sim":
        data = load_split("test")
        count = min(limit, len(data["seed"]))
        return [functools.partial(simulated_survey, i, data, gpr) for i in range(count)]
    return [_given(s) for s in fdtd_surveys(half)]


def _given(survey: Survey) -> Callable[[], Survey]:
    """A maker of a survey already built."""
    return lambda: survey


def fdtd_surveys(half: str = "test") -> list[Survey]:
    """Every FDTD scene of one half (the test half for reporting; the dev half is for tuning) as a survey."""
    cases = [c for c in fdtd_cases() if c.group == f"fdtd-{half}"]
    return [fdtd_survey(c, json.loads((FDTD_DATA / f"{c.name}.json").read_text())) for c in cases]


def fdtd_survey(case: Case, record: Mapping[str, Any]) -> Survey:
    """One FDTD scene's B-scan laid on every line of a drawn survey, and its pipes extruded across the lines."""
    seed = zlib.crc32(case.name.encode())
    rng = np.random.default_rng([_FDTD_TAG, seed])
    # lines, spacing, pose noise and receiver noise as a random straight-pipe scene draws them
    _, drawn = random_scene(rng, case="straight")
    bscan, gpr = case.load()
    along = bscan.along_track_m()
    spec = replace(drawn, length_m=float(along[-1]), centre_frequency_mhz=gpr.centre_frequency_mhz,
                   eps_r=float(record["eps_r"]), missing_lines=())
    truth = extruded_scene(record, spec)
    sigma = spec.noise_mv * float(np.max(np.abs(bscan.data))) / simulated_direct_wave_mv(truth, spec, gpr)
    bscans = {}
    for line in spec.kept_lines():
        true_xy = np.stack([along, np.full(len(along), spec.line_y(line))], axis=1)
        data = bscan.data + rng.normal(0.0, sigma, bscan.data.shape).astype(np.float32)
        bscans[line] = replace(bscan, data=data, positions=recorded_positions(true_xy, spec, rng),
                               times=np.arange(len(along)) * _TRACE_INTERVAL_S)
    region = survey_region(spec)
    dense, centre, scale = None, np.zeros(3), 1.0
    if truth.pipes:
        points, _ = sample_pipe_interiors(truth, DENSE_POINTS, np.random.default_rng([_FDTD_TAG, seed, 1]), region)
        centre, scale = normalisation(points)
        dense = np.asarray((points - centre) / scale, dtype=np.float32)
    return Survey(case.name, case.note, seed, bscans, gpr, truth, region, float(record["velocity_m_per_ns"]),
                  dense, centre, scale)


def extruded_scene(record: Mapping[str, Any], spec: SurveySpec) -> Scene:
    """The FDTD scene's pipes as straight rods along y across every line (and past them to the slab's edge)."""
    width = (spec.lines - 1) * spec.spacing_m
    y0, y1 = -_SLAB_MARGIN_M, width + _SLAB_MARGIN_M
    pipes = tuple(Pipe(f"{p['fill']}_{i}_x{100 * p['x_m']:.0f}cm", np.array([[p["x_m"], y0, -p["depth_m"]],
                                                                              [p["x_m"], y1, -p["depth_m"]]]),
                       float(p["radius_m"]), p["fill"]) for i, p in enumerate(record["pipes"]))
    deepest = max((p["depth_m"] + p["radius_m"] for p in record["pipes"]), default=0.0)
    bottom = record.get("slab_bottom_m") or max(0.3, deepest + 0.1)
    eps = float(record["eps_r"])
    loss = _DB_PER_M_PER_S_M * float(record["conductivity_s_per_m"]) / math.sqrt(eps)
    slab = Slab((spec.length_m + 2 * _SLAB_MARGIN_M, y1 - y0), (-_SLAB_MARGIN_M, y0), float(bottom), eps, loss)
    return Scene(str(record["name"]), f"FDTD {record['kind']}, extruded across {spec.lines} lines", slab, pipes,
                 None, None)


def simulated_direct_wave_mv(scene: Scene, spec: SurveySpec, gpr: GprConfig) -> float:
    """The simulator's direct-wave peak (mV) for this antenna: the FDTD noise is drawn at the simulator's
    noise-to-direct-wave ratio, so spec.noise_mv means on an FDTD line what it means on a simulated one."""
    quiet = replace(gpr_config(spec, scene, gpr), noise_mv=0.0)
    xy = np.array([[0.0, 0.0], [spec.length_m, 0.0]])
    empty = replace(scene, pipes=())
    return float(np.max(np.abs(simulate_bscan(empty, xy, quiet, np.random.default_rng(0)))))
