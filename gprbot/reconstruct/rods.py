"""Points sampled uniformly inside solid rods (pipes as polyline axes with a radius).

Each rod is the union of a cylinder per axis segment (flat ends) and a ball at every interior vertex
(filling the outer wedge of a bend). The union of all rods is sampled uniformly by drawing from the
primitives in proportion to their volume and keeping a draw with probability 1 / (number of primitives
that contain it), which cancels the double counting where primitives overlap (bends, tees, crossings).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

_CONTAIN_EPS = 1e-9


@dataclass(frozen=True)
class Primitive:
    """A cylinder (start, end, radius) or, when end is None, a ball (centre = start, radius)."""

    rod: int
    start: NDArray[np.float64]
    end: NDArray[np.float64] | None
    radius: float

    @property
    def volume(self) -> float:
        """The primitive's volume (m³)."""
        if self.end is None:
            return 4.0 / 3.0 * math.pi * self.radius**3
        return math.pi * self.radius**2 * float(np.linalg.norm(self.end - self.start))

    def contains(self, points: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Which points (M, 3) lie inside (a small tolerance for rounding)."""
        rel = points - self.start
        r2 = self.radius**2 + _CONTAIN_EPS
        if self.end is None:
            return np.asarray(np.sum(rel**2, axis=1) <= r2)
        axis = self.end - self.start
        length2 = float(axis @ axis)
        t = rel @ axis / length2
        radial2 = np.sum(rel**2, axis=1) - t * t * length2
        return np.asarray((t >= -_CONTAIN_EPS) & (t <= 1.0 + _CONTAIN_EPS) & (radial2 <= r2))

    def sample(self, count: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """count points uniform inside the primitive."""
        if self.end is None:
            direction = rng.normal(size=(count, 3))
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            return self.start + direction * (self.radius * rng.random(count) ** (1.0 / 3.0))[:, None]
        axis = self.end - self.start
        unit = axis / np.linalg.norm(axis)
        helper = np.array([1.0, 0.0, 0.0]) if abs(unit[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = np.cross(unit, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(unit, e1)
        radial = self.radius * np.sqrt(rng.random(count))
        angle = rng.uniform(0.0, 2.0 * math.pi, count)
        along = rng.random(count)
        return np.asarray(
            self.start
            + np.outer(along, axis)
            + np.outer(radial * np.cos(angle), e1)
            + np.outer(radial * np.sin(angle), e2),
            dtype=np.float64,
        )


def rod_primitives(axes: Sequence[NDArray[np.float64]], radii: Sequence[float]) -> list[Primitive]:
    """Cylinders for every segment and balls at interior vertices of each rod."""
    primitives = []
    for rod, (axis, radius) in enumerate(zip(axes, radii, strict=True)):
        for a, b in itertools.pairwise(axis):
            if np.linalg.norm(b - a) > 1e-9:
                primitives.append(Primitive(rod, a, b, radius))
        primitives += [Primitive(rod, vertex, None, radius) for vertex in axis[1:-1]]
    return primitives


def sample_rods(
    axes: Sequence[NDArray[np.float64]], radii: Sequence[float], n: int, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """n points uniform inside the union of the rods, and the rod index of each point."""
    primitives = rod_primitives(axes, radii)
    if n <= 0 or not primitives:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.intp)
    volumes = np.array([p.volume for p in primitives])
    weights = volumes / volumes.sum()
    points: list[NDArray[np.float64]] = []
    labels: list[NDArray[np.intp]] = []
    have = 0
    while have < n:
        counts = rng.multinomial(int(1.5 * (n - have)) + 16, weights)
        for primitive, count in zip(primitives, counts, strict=True):
            if count == 0:
                continue
            draws = primitive.sample(int(count), rng)
            cover = np.maximum(sum(p.contains(draws).astype(np.intp) for p in primitives), 1)
            keep = rng.random(len(draws)) * cover < 1.0
            points.append(draws[keep])
            labels.append(np.full(int(np.count_nonzero(keep)), primitive.rod, dtype=np.intp))
            have += int(np.count_nonzero(keep))
    order = rng.permutation(have)[:n]
    return np.concatenate(points)[order], np.concatenate(labels)[order]
