"""Random scenes and surveys for training and evaluating the learned stages (MigrationNet, GPRNet).

Survey lines run along +x at y = start_y + i * spacing; every pipe segment crosses them at 45° or
more (its direction lies within ±45° of the y axis). What varies is what varies on real sites: pipe
count, radius, cover, crossing angle, straight runs, elbows, tees, fill, permittivity, antenna
frequency, line spacing, pose noise, missing lines, rebar mesh, aggregate clutter and receiver noise.
Everything is drawn from the `rng` passed in, so a seed gives the same scene on every machine.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from gprbot.config import GprConfig
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.sim.scene import FILLS, Clutter, Fill, Pipe, Rebar, Scene, Slab

FloatArray = NDArray[np.float64]
Case = Literal["straight", "oblique", "bend", "tee", "multi", "missing"]
CASES: tuple[Case, ...] = ("straight", "oblique", "bend", "tee", "multi", "missing")

SPLIT_SIZES = {"train": 1378, "val": 100, "test": 150}  # the paper's dataset sizes
_SPLIT_BASE = {"train": 0, "val": 100_000, "test": 200_000}  # disjoint seed ranges
_SLAB_MARGIN_M = 0.3  # slab extends this far beyond the surveyed rectangle
_MAX_ANGLE_DEG = 44.0  # from perpendicular to the lines (under 45° so rounding keeps every crossing >= 45°)
_TRACE_SPACING_M = 0.005  # 0.1 m/s at 20 traces/s, the default survey
_MIN_CLEARANCE_M = 0.02  # between the surfaces of two different pipes


@dataclass(frozen=True)
class SurveySpec:
    """A survey of parallel lines along +x: count, spacing, length, start, antenna and site parameters.

    `missing_lines` are lines whose B-scans are dropped (a skipped or corrupted slice).
    """

    lines: int
    spacing_m: float
    length_m: float
    start_xy: tuple[float, float]
    centre_frequency_mhz: float
    eps_r: float
    pose_noise_m: float
    missing_lines: tuple[int, ...]
    noise_mv: float = 0.5

    def line_y(self, line: int) -> float:
        """The y of line `line` (m)."""
        return self.start_xy[1] + line * self.spacing_m

    def kept_lines(self) -> tuple[int, ...]:
        """The lines whose B-scans exist (all but the missing ones)."""
        return tuple(i for i in range(self.lines) if i not in self.missing_lines)


def line_antenna_xy(spec: SurveySpec, line: int, trace_spacing_m: float = _TRACE_SPACING_M) -> FloatArray:
    """True antenna midpoints (N, 2) of one line, every `trace_spacing_m` along +x."""
    n = round(spec.length_m / trace_spacing_m) + 1
    x = spec.start_xy[0] + np.arange(n) * trace_spacing_m
    return np.stack([x, np.full(n, spec.line_y(line))], axis=1)


def recorded_positions(true_xy: FloatArray, spec: SurveySpec, rng: np.random.Generator) -> FloatArray:
    """Positions (N, 3) as the pose estimate records them: the true ones plus white noise of pose_noise_m."""
    xy = np.asarray(true_xy, dtype=np.float64) + rng.normal(0.0, spec.pose_noise_m, size=(len(true_xy), 2))
    return np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)


def gpr_config(spec: SurveySpec, scene: Scene, base: GprConfig | None = None) -> GprConfig:
    """The antenna settings for a survey: its frequency and noise, a time window reaching the slab bottom."""
    base = base or GprConfig()
    v = velocity_from_eps(scene.slab.eps_r)
    needed_ns = base.pre_trigger_ns + 2.0 * (scene.slab.thickness_m + 0.05) / v
    window = max(base.time_window_ns, math.ceil(needed_ns))
    samples = 32 * math.ceil(window / base.dt_ns / 32)  # keep the base sample interval
    return replace(base, centre_frequency_mhz=spec.centre_frequency_mhz, noise_mv=spec.noise_mv,
                   time_window_ns=float(samples * base.dt_ns), samples=samples)


def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """The scene as the mapping a scene YAML file holds (pipe points as [x, y, depth]); parse_scene reads it."""
    slab = scene.slab
    data: dict[str, Any] = {
        "name": scene.name,
        "description": scene.description,
        "slab": {"size_m": list(slab.size_m), "origin_m": list(slab.origin_m), "thickness_m": slab.thickness_m,
                 "eps_r": slab.eps_r, "loss_db_per_m": slab.loss_db_per_m},
        "pipes": [{"name": p.name, "points": [[float(x), float(y), float(-z)] for x, y, z in p.points],
                   "radius_m": p.radius_m, "fill": p.fill} for p in scene.pipes],
        "rebar": None if scene.rebar is None else asdict(scene.rebar),
        "clutter": None if scene.clutter is None else asdict(scene.clutter),
    }
    if scene.clutter is not None:
        data["clutter"]["depth_range_m"] = list(scene.clutter.depth_range_m)
    return data


def split_seeds(split: Literal["train", "val", "test"]) -> range:
    """The fixed seeds of a split: train 1378, val 100, test 150 scenes, disjoint."""
    base = _SPLIT_BASE[split]
    return range(base, base + SPLIT_SIZES[split])


def scene_for_seed(seed: int) -> tuple[Scene, SurveySpec]:
    """The scene of a split seed; cases cycle with the seed so every split holds all cases equally."""
    return random_scene(np.random.default_rng([seed, 0x6770]), case=CASES[seed % len(CASES)])


def random_scene(rng: np.random.Generator, *, case: str | None = None) -> tuple[Scene, SurveySpec]:
    """A random slab with pipes of the given case (random if None) and the survey that covers it."""
    if case is None:
        case = CASES[int(rng.integers(len(CASES)))]
    if case not in CASES:
        raise ValueError(f"unknown case {case!r}; expected one of {', '.join(CASES)}")
    lines = int(rng.integers(5, 13))
    spacing = round(float(rng.uniform(0.05, 0.25)), 3)
    length = round(float(rng.uniform(1.2, 2.5)), 2)
    frequency = _draw_frequency(rng)
    eps_r = float(rng.uniform(4.0, 12.0))
    missing: tuple[int, ...] = ()
    if case == "missing":
        count = int(rng.integers(1, min(3, lines - 3) + 1))
        missing = tuple(sorted(int(i) for i in rng.choice(np.arange(1, lines - 1), size=count, replace=False)))
    spec = SurveySpec(lines, spacing, length, (0.0, 0.0), frequency, eps_r, float(rng.uniform(0.0, 0.01)),
                      missing, float(rng.uniform(0.2, 2.0)))
    width = (lines - 1) * spacing
    slab_xy = (-_SLAB_MARGIN_M, -_SLAB_MARGIN_M, round(length + _SLAB_MARGIN_M, 4), round(width + _SLAB_MARGIN_M, 4))
    rebar = _draw_rebar(rng) if rng.random() < 0.25 else None
    min_cover = 0.05 if rebar is None else rebar.cover_m + 2 * rebar.diameter_m + 0.03
    pipes = _draw_pipes(rng, case, slab_xy, width, min_cover)
    deepest = max(float(-p.points[:, 2].min()) + p.radius_m for p in pipes)
    thickness = round(max(0.3, deepest + float(rng.uniform(0.05, 0.2))), 4)
    slab = Slab((slab_xy[2] - slab_xy[0], slab_xy[3] - slab_xy[1]), (slab_xy[0], slab_xy[1]), thickness,
                eps_r, float(rng.uniform(5.0, 30.0)))
    clutter = None
    if rng.random() < 0.3:
        clutter = Clutter(int(rng.integers(50, 300)), float(rng.uniform(0.004, 0.012)),
                          (0.02, thickness - 0.02), int(rng.integers(0, 2**31 - 1)))
    name = f"random_{case}"
    description = f"{case}: {len(pipes)} pipe(s), eps_r {eps_r:.1f}, {frequency:.0f} MHz, {lines} lines"
    return Scene(name, description, slab, tuple(pipes), rebar, clutter), spec


def _draw_frequency(rng: np.random.Generator) -> float:
    """Centre frequency: mostly 900–1600 MHz (concrete scanning), sometimes 400–900 or 1600–2600."""
    u = rng.random()
    if u < 0.7:
        return float(rng.uniform(900.0, 1600.0))
    if u < 0.85:
        return float(rng.uniform(400.0, 900.0))
    return float(rng.uniform(1600.0, 2600.0))


def _draw_rebar(rng: np.random.Generator) -> Rebar:
    directions: Literal["x", "y", "xy"] = ("x", "y", "xy")[int(rng.integers(3))]  # type: ignore[assignment]
    return Rebar(float(rng.uniform(0.15, 0.3)), float(rng.uniform(0.03, 0.06)), float(rng.uniform(0.01, 0.016)),
                 directions)


def _draw_pipes(
    rng: np.random.Generator, case: str, slab_xy: tuple[float, float, float, float], width: float, min_cover: float
) -> list[Pipe]:
    """Pipes for a case, redrawn until no two pipes come closer than the clearance."""
    count = {"multi": int(rng.integers(2, 5)), "tee": 1}.get(case, 1 if rng.random() < 0.7 else 2)
    pipes: list[Pipe] = []
    attempts = 0
    while len(pipes) < count and attempts < 200:
        attempts += 1
        kind = case
        if case in ("multi", "missing") or pipes:
            kind = ("straight", "oblique", "bend")[int(rng.integers(3))]
        new = _draw_one(rng, kind, slab_xy, width, min_cover, len(pipes))
        if all(_clear(a, b) for a in new for b in pipes) and (len(new) == 1 or _clear(new[0], new[1], junction=True)):
            pipes.extend(new)
    return pipes


def _draw_one(
    rng: np.random.Generator, kind: str, slab_xy: tuple[float, float, float, float], width: float,
    min_cover: float, index: int,
) -> list[Pipe]:
    """One pipe (or a tee: main and branch) crossing the survey."""
    x1 = slab_xy[2]
    radius = float(np.exp(rng.uniform(math.log(0.01), math.log(0.1))))
    cover = float(rng.uniform(max(min_cover, 0.05), 0.4))
    depth = round(cover + radius, 4)
    fill: Fill = FILLS[int(rng.choice(3, p=[0.45, 0.35, 0.2]))]
    centre = np.array([rng.uniform(0.2, x1 - _SLAB_MARGIN_M - 0.2), rng.uniform(0.0, width)])
    max_angle = math.radians(_MAX_ANGLE_DEG)
    if kind == "oblique":
        angle = float(rng.choice([-1.0, 1.0]) * rng.uniform(math.radians(25.0), max_angle))
    else:
        angle = float(rng.uniform(-max_angle, max_angle) * (0.4 if kind == "straight" else 1.0))
    name = f"pipe{index}"
    if kind == "bend":
        turn = float(rng.choice([-1.0, 1.0]) * rng.uniform(math.radians(20.0), math.radians(60.0)))
        second = float(np.clip(angle + turn, -max_angle, max_angle))
        down = _ray_to_edge(centre, angle + math.pi, slab_xy)
        up = _ray_to_edge(centre, second, slab_xy)
        points = [down, centre, up]
        return [_pipe(name, points, depth, radius, fill)]
    a, b = _ray_to_edge(centre, angle + math.pi, slab_xy), _ray_to_edge(centre, angle, slab_xy)
    main = _pipe(name, [a, b], depth, radius, fill)
    if kind != "tee":
        return [main]
    offset = float(rng.choice([-1.0, 1.0]) * rng.uniform(math.radians(30.0), math.radians(80.0)))
    branch_angle = float(np.clip(angle + offset, -max_angle, max_angle))
    if abs(branch_angle - angle) < math.radians(25.0):
        branch_angle = angle - math.copysign(math.radians(30.0), offset)
    heading = branch_angle if rng.random() < 0.5 else branch_angle + math.pi
    branch_radius = float(rng.uniform(0.5, 1.0)) * radius
    end = _ray_to_edge(centre, heading, slab_xy)
    branch = _pipe(f"pipe{index}_branch", [centre, end], depth, max(branch_radius, 0.01), fill)
    return [main, branch]


def _ray_to_edge(start: FloatArray, angle_from_y: float, slab_xy: tuple[float, float, float, float]) -> FloatArray:
    """The point where a ray from `start` (direction angle_from_y from +y, towards +x) leaves the slab."""
    x0, y0, x1, y1 = slab_xy
    d = np.array([math.sin(angle_from_y), math.cos(angle_from_y)])
    limits = []
    for k, (lo, hi) in enumerate(((x0, x1), (y0, y1))):
        if abs(d[k]) > 1e-9:
            limits.append(((hi if d[k] > 0 else lo) - start[k]) / d[k])
    return np.asarray(start + min(limits) * d)


def _pipe(name: str, xy: list[FloatArray], depth: float, radius: float, fill: Fill) -> Pipe:
    points = np.array([[p[0], p[1], -depth] for p in xy], dtype=np.float64)
    return Pipe(name, np.round(points, 4), round(radius, 4), fill)


def _axis_samples(pipe: Pipe, step: float = 0.01) -> FloatArray:
    parts = []
    for a, b in pipe.segments():
        n = max(2, int(np.linalg.norm(b - a) / step) + 1)
        parts.append(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
    return np.concatenate(parts)


def _clear(a: Pipe, b: Pipe, *, junction: bool = False) -> bool:
    """Whether two pipes keep the clearance; a tee's branch only has to stay clear beyond the junction."""
    pa, pb = _axis_samples(a), _axis_samples(b)
    if junction:
        near_junction = np.linalg.norm(pb - b.points[0], axis=1) <= a.radius_m + b.radius_m + 0.05
        pb = pb[~near_junction]
        if len(pb) == 0:
            return True
    distance = np.sqrt(((pa[:, None, :] - pb[None, :, :]) ** 2).sum(-1)).min()
    return bool(distance >= a.radius_m + b.radius_m + _MIN_CLEARANCE_M)
