"""Scenes of the simulated world: a concrete slab with pipes, an optional rebar mesh and aggregate clutter.

Site frame: x forward (survey lines run along x), y left, z up; the slab's top surface is z = 0.
Scene files give pipe axis points as `[x, y, depth]` (depth of the axis below the surface, positive);
inside, points are site-frame (x, y, z) with z = -depth.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Literal, cast

import numpy as np
import yaml
from numpy.typing import NDArray

from gprbot.errors import ConfigError

Fill = Literal["metal", "pvc-air", "pvc-water"]
FILLS: tuple[Fill, ...] = ("metal", "pvc-air", "pvc-water")
_TOLERANCE_M = 1e-6


@dataclass(frozen=True)
class Slab:
    """The concrete slab: footprint size and lower-left corner (m), thickness, permittivity, loss, what is below."""

    size_m: tuple[float, float]
    origin_m: tuple[float, float]
    thickness_m: float
    eps_r: float
    loss_db_per_m: float
    below_eps_r: float = 15.0  # under the bottom face: moist soil (15); 1 for air under a suspended slab

    def contains_xy(self, x: float, y: float) -> bool:
        """Whether the horizontal point (x, y) lies on the slab's footprint."""
        x0, y0 = self.origin_m
        return bool(
            x0 - _TOLERANCE_M <= x <= x0 + self.size_m[0] + _TOLERANCE_M
            and y0 - _TOLERANCE_M <= y <= y0 + self.size_m[1] + _TOLERANCE_M
        )


@dataclass(frozen=True, eq=False)
class Pipe:
    """A pipe: its axis as a polyline of site-frame points (K, 3), z < 0, its outer radius and fill."""

    name: str
    points: NDArray[np.float64]
    radius_m: float
    fill: Fill

    def __post_init__(self) -> None:
        pts = np.array(self.points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
            raise ConfigError(f"pipe {self.name!r}: points must be a list of at least 2 [x, y, z] points")
        pts.setflags(write=False)
        object.__setattr__(self, "points", pts)

    def segments(self) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """The straight runs of the axis as (start, end) point pairs."""
        return [(self.points[i], self.points[i + 1]) for i in range(len(self.points) - 1)]

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Pipe):
            return NotImplemented
        return (self.name, self.radius_m, self.fill) == (other.name, other.radius_m, other.fill) and bool(
            np.array_equal(self.points, other.points)
        )

    def __hash__(self) -> int:
        return hash((self.name, self.radius_m, self.fill, self.points.tobytes()))


@dataclass(frozen=True)
class Rebar:
    """A reinforcement mesh: bar spacing, cover above the top layer, bar diameter, bar directions."""

    spacing_m: float
    cover_m: float
    diameter_m: float
    directions: Literal["x", "y", "xy"]


@dataclass(frozen=True)
class Clutter:
    """Aggregate clutter: `count` small scatterers up to max_radius_m, between two depths (m)."""

    count: int
    max_radius_m: float
    depth_range_m: tuple[float, float]
    seed: int


@dataclass(frozen=True)
class Scene:
    """A simulated site: the slab, its pipes, and optional rebar mesh and clutter."""

    name: str
    description: str
    slab: Slab
    pipes: tuple[Pipe, ...]
    rebar: Rebar | None
    clutter: Clutter | None

    def rebar_bars(self) -> tuple[Pipe, ...]:
        """The rebar mesh as metal pipes spanning the slab; with "xy", the y-running bars lie on top."""
        if self.rebar is None:
            return ()
        rebar, slab = self.rebar, self.slab
        radius = rebar.diameter_m / 2.0
        x0, y0 = slab.origin_m
        x1, y1 = x0 + slab.size_m[0], y0 + slab.size_m[1]
        bars: list[Pipe] = []
        depth = rebar.cover_m + radius
        for direction in ("y", "x"):
            if direction not in rebar.directions:
                continue
            lo, hi = (x0, x1) if direction == "y" else (y0, y1)
            across = np.arange(lo + rebar.spacing_m / 2.0, hi, rebar.spacing_m)
            for i, c in enumerate(across):
                ends = [[c, y0, -depth], [c, y1, -depth]] if direction == "y" else [[x0, c, -depth], [x1, c, -depth]]
                bars.append(Pipe(f"rebar_{direction}{i:02d}", np.array(ends), radius, "metal"))
            depth += rebar.diameter_m
        return tuple(bars)


# ---------------------------------------------------------------------------------------- parsing


def _mapping(value: Any, path: str, required: tuple[str, ...], optional: tuple[str, ...]) -> dict[str, Any]:
    """Check that `value` is a mapping with all required keys and no unknown ones."""
    if not isinstance(value, dict):
        raise ConfigError(f"{path}: expected a mapping, got {value!r}")
    known = required + optional
    for key in value:
        if key not in known:
            raise ConfigError(f"{_join(path, key)}: unknown key (known keys here: {', '.join(sorted(known))})")
    for key in required:
        if key not in value:
            raise ConfigError(f"{_join(path, key)}: missing (required)")
    return value


def _join(path: str, key: Any) -> str:
    return f"{path}.{key}" if path else str(key)


def _number(value: Any, path: str, *, positive: bool = False, non_negative: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise ConfigError(f"{path}: expected a {'positive ' if positive else ''}number, got {value!r}")
    if positive and value <= 0:
        raise ConfigError(f"{path}: expected a positive number, got {value!r}")
    if non_negative and value < 0:
        raise ConfigError(f"{path}: expected a number >= 0, got {value!r}")
    return float(value)


def _numbers(value: Any, path: str, n: int) -> tuple[float, ...]:
    if not isinstance(value, list | tuple) or len(value) != n:
        raise ConfigError(f"{path}: expected a list of {n} numbers, got {value!r}")
    return tuple(_number(v, f"{path}[{i}]") for i, v in enumerate(value))


def _integer(value: Any, path: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ConfigError(f"{path}: expected an integer >= 0, got {value!r}")
    return value


def _string(value: Any, path: str) -> str:
    if not isinstance(value, str):
        raise ConfigError(f"{path}: expected a string, got {value!r}")
    return value


def _parse_slab(value: Any, path: str) -> Slab:
    d = _mapping(value, path, ("size_m", "origin_m", "thickness_m", "eps_r", "loss_db_per_m"), ("below_eps_r",))
    size = _numbers(d["size_m"], f"{path}.size_m", 2)
    if min(size) <= 0:
        raise ConfigError(f"{path}.size_m: expected two positive numbers, got {d['size_m']!r}")
    eps_r = _number(d["eps_r"], f"{path}.eps_r", positive=True)
    if eps_r < 1.0:
        raise ConfigError(f"{path}.eps_r: expected a relative permittivity >= 1, got {eps_r!r}")
    return Slab(
        size_m=(size[0], size[1]),
        origin_m=cast(tuple[float, float], _numbers(d["origin_m"], f"{path}.origin_m", 2)),
        thickness_m=_number(d["thickness_m"], f"{path}.thickness_m", positive=True),
        eps_r=eps_r,
        loss_db_per_m=_number(d["loss_db_per_m"], f"{path}.loss_db_per_m", non_negative=True),
        below_eps_r=_number(d.get("below_eps_r", 15.0), f"{path}.below_eps_r", positive=True),
    )


def _parse_pipe(value: Any, path: str, slab: Slab) -> Pipe:
    d = _mapping(value, path, ("name", "points", "radius_m", "fill"), ())
    name = _string(d["name"], f"{path}.name")
    radius = _number(d["radius_m"], f"{path}.radius_m", positive=True)
    if d["fill"] not in FILLS:
        raise ConfigError(f"{path}.fill: expected one of {', '.join(FILLS)}, got {d['fill']!r}")
    raw = d["points"]
    if not isinstance(raw, list) or len(raw) < 2:
        raise ConfigError(f"{path}.points: expected a list of at least 2 [x, y, depth] points, got {raw!r}")
    points: list[tuple[float, float, float]] = []
    for i, p in enumerate(raw):
        x, y, depth = _numbers(p, f"{path}.points[{i}]", 3)
        if depth - radius < 0:
            raise ConfigError(f"{path}.points[{i}]: the pipe rises above the surface (depth {depth} m < radius)")
        if depth + radius > slab.thickness_m:
            raise ConfigError(f"{path}.points[{i}]: the pipe reaches below the slab (depth + radius > thickness)")
        if not slab.contains_xy(x, y):
            raise ConfigError(f"{path}.points[{i}]: ({x}, {y}) lies outside the slab's footprint")
        if points and np.allclose(points[-1][:2], (x, y)) and abs(points[-1][2] + depth) < _TOLERANCE_M:
            raise ConfigError(f"{path}.points[{i}]: repeats the previous point")
        points.append((x, y, -depth))
    return Pipe(name, np.array(points), radius, cast(Fill, d["fill"]))


def _parse_rebar(value: Any, path: str, slab: Slab) -> Rebar:
    d = _mapping(value, path, ("spacing_m", "cover_m", "diameter_m", "directions"), ())
    if d["directions"] not in ("x", "y", "xy"):
        raise ConfigError(f"{path}.directions: expected one of x, y, xy, got {d['directions']!r}")
    rebar = Rebar(
        spacing_m=_number(d["spacing_m"], f"{path}.spacing_m", positive=True),
        cover_m=_number(d["cover_m"], f"{path}.cover_m", positive=True),
        diameter_m=_number(d["diameter_m"], f"{path}.diameter_m", positive=True),
        directions=d["directions"],
    )
    if rebar.cover_m + len(rebar.directions) * rebar.diameter_m > slab.thickness_m:
        raise ConfigError(f"{path}.cover_m: the mesh reaches below the slab")
    return rebar


def _parse_clutter(value: Any, path: str, slab: Slab) -> Clutter:
    d = _mapping(value, path, ("count", "max_radius_m", "depth_range_m", "seed"), ())
    lo, hi = _numbers(d["depth_range_m"], f"{path}.depth_range_m", 2)
    if not 0 <= lo < hi <= slab.thickness_m:
        raise ConfigError(f"{path}.depth_range_m: expected 0 <= min < max <= slab thickness, got {[lo, hi]}")
    return Clutter(
        count=_integer(d["count"], f"{path}.count"),
        max_radius_m=_number(d["max_radius_m"], f"{path}.max_radius_m", positive=True),
        depth_range_m=(lo, hi),
        seed=_integer(d["seed"], f"{path}.seed"),
    )


def parse_scene(data: dict[str, Any], source: str) -> Scene:
    """Build a Scene from parsed YAML; errors name `source` and the key path (e.g. pipes[2].radius_m)."""
    try:
        d = _mapping(data, "", ("slab",), ("name", "description", "pipes", "rebar", "clutter"))
        slab = _parse_slab(d["slab"], "slab")
        raw_pipes = d.get("pipes") or []
        if not isinstance(raw_pipes, list):
            raise ConfigError(f"pipes: expected a list of pipes, got {raw_pipes!r}")
        pipes = tuple(_parse_pipe(p, f"pipes[{i}]", slab) for i, p in enumerate(raw_pipes))
        names = [p.name for p in pipes]
        for i, name in enumerate(names):
            if name in names[:i]:
                raise ConfigError(f"pipes[{i}].name: {name!r} is used twice; give each pipe its own name")
        rebar = d.get("rebar")
        clutter = d.get("clutter")
        return Scene(
            name=_string(d.get("name", Path(source).stem), "name"),
            description=_string(d.get("description", ""), "description"),
            slab=slab,
            pipes=pipes,
            rebar=None if rebar is None else _parse_rebar(rebar, "rebar", slab),
            clutter=None if clutter is None else _parse_clutter(clutter, "clutter", slab),
        )
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def builtin_scene_names() -> list[str]:
    """Names of the scenes shipped in gprbot/sim/scenes/."""
    folder = resources.files("gprbot.sim").joinpath("scenes")
    return sorted(f.name[: -len(".yaml")] for f in folder.iterdir() if f.name.endswith(".yaml"))


def load_scene(name_or_path: str) -> Scene:
    """Load a built-in scene by name (e.g. "paper_slab") or a scene YAML file by path."""
    if name_or_path in builtin_scene_names():
        source = f"{name_or_path}.yaml"
        text = resources.files("gprbot.sim").joinpath("scenes").joinpath(source).read_text()
    else:
        source = name_or_path
        try:
            text = Path(name_or_path).read_text()
        except OSError as exc:
            known = ", ".join(builtin_scene_names())
            raise ConfigError(
                f"cannot read scene {name_or_path!r} ({exc.strerror}): give a YAML path or one of {known}"
            ) from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: not valid YAML ({exc})") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: the top level must be a mapping with at least a 'slab' section")
    return parse_scene(data, source)
