"""Ground truth of a scene's pipes as solid rods: cross-section masks and uniform interior samples.

A pipe is the union of one solid cylinder per axis segment (flat at the pipe's two ends) and a ball
at each interior joint, so an elbow is closed on the outside of the bend. Rebar and clutter are not
targets and are left out.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gprbot.errors import ConfigError
from gprbot.geometry import Primitive, rod_primitives, sample_rods
from gprbot.sim.scene import Scene

FloatArray = NDArray[np.float64]


def _rods(scene: Scene) -> list[Primitive]:
    """The pipes of the scene as solid pieces (rod index = pipe index)."""
    return rod_primitives([p.points for p in scene.pipes], [p.radius_m for p in scene.pipes])


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
    for solid in _rods(scene):
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
    Where pipes overlap (a tee's junction) the point belongs to the pipe listed first. The sampler is the
    completion's too (gprbot.geometry.sample_rods), so truth and completion sample alike.
    """
    if not scene.pipes:
        raise ConfigError(f"scene {scene.name!r} has no pipes to sample; add pipes to the scene file")
    points, owners = sample_rods([p.points for p in scene.pipes], [p.radius_m for p in scene.pipes], n, rng, region_xy)
    if len(points) < n:
        raise ConfigError(
            f"scene {scene.name!r}: no pipe lies inside region {region_xy}; widen region_xy or check the scene"
        )
    return points, owners
