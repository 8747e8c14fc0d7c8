"""A 3D picture (PNG) of the dense cloud and the pipes' axes under the surveyed area, for a report."""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from gprbot.plotting import new_figure, save_png
from gprbot.reconstruct.completion import Reconstruction, pipe_colors

MAX_POINTS = 6000  # enough to show the rods; more only slows matplotlib's 3D scatter


def render_3d(path: str | os.PathLike[str], reconstruction: Reconstruction,
              survey_lines: Sequence[NDArray[np.float64]] = (), rng_seed: int = 0) -> None:
    """Dense cloud coloured per pipe, pipe axes, survey lines on the surface; axes in metres at true scale."""
    fig = new_figure((9.0, 6.5))
    ax = fig.add_subplot(1, 1, 1, projection="3d")
    dense = np.asarray(reconstruction.dense, dtype=np.float64)
    colours = pipe_colors(max(len(reconstruction.pipes), 1)) / 255.0
    if len(dense):
        keep = np.random.default_rng(rng_seed).permutation(len(dense))[:MAX_POINTS]
        labels = np.asarray(reconstruction.labels)[keep]
        ax.scatter(dense[keep, 0], dense[keep, 1], dense[keep, 2], c=colours[labels], s=1.5, depthshade=False)
    for index, pipe in enumerate(reconstruction.pipes):
        a = pipe.axis
        ax.plot(a[:, 0], a[:, 1], a[:, 2], color="black", linewidth=1.0)
        ax.text(a[-1, 0], a[-1, 1], a[-1, 2], f" P{index} Ø{pipe.diameter_m * 100:.0f} cm", fontsize=8)
    for line in survey_lines:
        xy = np.asarray(line, dtype=np.float64)
        ax.plot(xy[:, 0], xy[:, 1], np.zeros(len(xy)), color="#8cb4e6", linewidth=0.6)
    points = [dense] + [p.axis for p in reconstruction.pipes] + [np.column_stack([np.asarray(s)[:, :2],
                                                                                  np.zeros(len(s))])
                                                                 for s in survey_lines if len(s)]
    stacked = np.concatenate([p for p in points if len(p)]) if any(len(p) for p in points) else np.zeros((1, 3))
    lo, hi = stacked.min(axis=0), stacked.max(axis=0)
    lo[2], hi[2] = min(lo[2], -0.05), 0.0  # the surface is the top of the box
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(float(v) for v in np.maximum(hi - lo, 1e-3)))  # true scale on all three axes
    ax.set_xlabel("site x (m)")
    ax.set_ylabel("site y (m)")
    ax.set_zlabel("z (m)")
    ax.view_init(elev=28, azim=-60)
    ax.set_title(f"{len(reconstruction.pipes)} pipes, {len(dense)} dense points "
                 f"(shown: {min(len(dense), MAX_POINTS)}); true scale; surface at z = 0, survey lines blue",
                 fontsize=9)
    save_png(fig, path)
