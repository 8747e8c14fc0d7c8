"""Ground truth of a scene's pipes as solid rods: cross-section masks and uniform interior samples.

A pipe is the union of one solid cylinder per axis segment (flat at the pipe's two ends) and a ball
at each interior joint, so an elbow is closed on the outside of the bend. Rebar and clutter are not
targets and are left out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import ConfigError
from gprbot.sim.scene import Scene

FloatArray = NDArray[np.float64]
_MAX_BATCH = 1_000_000  # candidate points per round of rejection sampling


@dataclass(frozen=True)
class _Solid:
    """One solid piece of a pipe: a cylinder from a to b, or a ball at a (b is None)."""

    pipe_index: int
    a: FloatArray
    b: FloatArray | None
    radius: float

    @property
    def volume(self) -> float:
        if self.b is None:
            return 4.0 / 3.0 * math.pi * self.radius**3
        return math.pi * self.radius**2 * float(np.linalg.norm(self.b - self.a))

    def contains(self, points: FloatArray) -> NDArray[np.bool_]:
        """Which of the points (..., 3) lie inside this solid."""
        rel = points - self.a
        if self.b is None:
            return np.asarray(np.sum(rel**2, axis=-1) <= self.radius**2)
        ab = self.b - self.a
        s = (rel @ ab) / float(ab @ ab)
        radial = rel - s[..., None] * ab
        return np.asarray((s >= 0.0) & (s <= 1.0) & (np.sum(radial**2, axis=-1) <= self.radius**2))

    def sample(self, m: int, rng: np.random.Generator) -> FloatArray:
        """m points uniform inside this solid."""
        if self.b is None:
            direction = rng.standard_normal((m, 3))
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            return np.asarray(self.a + direction * (self.radius * rng.random(m) ** (1.0 / 3.0))[:, None])
        ab = self.b - self.a
        u = ab / np.linalg.norm(ab)
        e1 = np.cross(u, [0.0, 0.0, 1.0] if abs(u[2]) < 0.9 else [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(u, e1)
        r = self.radius * np.sqrt(rng.random(m))
        phi = 2.0 * math.pi * rng.random(m)
        along = rng.random(m)
        return np.asarray(
            self.a + along[:, None] * ab + (r * np.cos(phi))[:, None] * e1 + (r * np.sin(phi))[:, None] * e2
        )


def _solids(scene: Scene) -> list[_Solid]:
    """The pipes of the scene as solid pieces, in pipe order."""
    solids: list[_Solid] = []
    for index, pipe in enumerate(scene.pipes):
        for a, b in pipe.segments():
            solids.append(_Solid(index, a, b, pipe.radius_m))
        for joint in pipe.points[1:-1]:
            solids.append(_Solid(index, joint, None, pipe.radius_m))
    return solids


def cross_section_mask(scene: Scene, column_xy: FloatArray, z_m: FloatArray) -> NDArray[np.bool_]:
    """Mask (nz, nx): True where the vertical plane through the columns (nx, 2) cuts a pipe's interior.

    `z_m` are depths (positive down) of the rows. Rebar and clutter are excluded.
    """
    columns = np.asarray(column_xy, dtype=np.float64)
    depths = np.asarray(z_m, dtype=np.float64)
    grid = np.empty((len(depths), len(columns), 3))
    grid[..., :2] = columns[None, :, :]
    grid[..., 2] = -depths[:, None]
    mask = np.zeros((len(depths), len(columns)), dtype=bool)
    for solid in _solids(scene):
        mask |= solid.contains(grid)
    return mask


def sample_pipe_interiors(
    scene: Scene,
    n: int,
    rng: np.random.Generator,
    region_xy: tuple[float, float, float, float] | None = None,
) -> tuple[FloatArray, NDArray[np.int64]]:
    """n points (n, 3) uniform inside the pipes' solid rods, and the index of the pipe of each point.

    With `region_xy` = (xmin, xmax, ymin, ymax) only the part of the pipes above that area counts.
    Where pipes overlap (a tee's junction) the point belongs to the pipe listed first.
    """
    solids = _solids(scene)
    if not solids:
        raise ConfigError(f"scene {scene.name!r} has no pipes to sample; add pipes to the scene file")
    volumes = np.array([s.volume for s in solids])
    chosen: list[FloatArray] = []
    owners: list[NDArray[np.int64]] = []
    have, batch = 0, max(2 * n, 1024)
    for _ in range(30):
        picks = rng.choice(len(solids), size=batch, p=volumes / volumes.sum())
        counts = np.bincount(picks, minlength=len(solids))
        for k, solid in enumerate(solids):
            if counts[k] == 0:
                continue
            points = solid.sample(int(counts[k]), rng)
            # Uniform over the union: a point counts only for the first solid that contains it.
            keep = ~np.any([solids[j].contains(points) for j in range(k)], axis=0) if k else np.ones(len(points), bool)
            if region_xy is not None:
                xmin, xmax, ymin, ymax = region_xy
                x, y = points[:, 0], points[:, 1]
                keep &= (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)
            chosen.append(points[keep])
            owners.append(np.full(int(keep.sum()), solid.pipe_index, dtype=np.int64))
            have += int(keep.sum())
        if have >= n or (have == 0 and batch >= _MAX_BATCH):
            break
        batch = int(min(_MAX_BATCH, batch * (4.0 if have == 0 else max(1.5, 1.2 * n / have))))
    if have < n:
        raise ConfigError(
            f"scene {scene.name!r}: no pipe lies inside region {region_xy}; widen region_xy or check the scene"
        )
    all_points, all_owners = np.concatenate(chosen), np.concatenate(owners)
    order = rng.permutation(len(all_points))[:n]
    return all_points[order], all_owners[order]
