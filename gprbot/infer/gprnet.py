"""GPRNet at run time: the sparse registered cloud (1500 points, metres) → a dense pipe cloud, via ONNX.

The cloud is normalised exactly as in training (training/pointcloud_data.py): centred on its bounding
box's centre and divided by the box's longest side, so the network always sees the unit cube; its
output is mapped back to metres with the same transform.

pipes.json with completion "gprnet": the pipes (axis, depth of cover, diameter, confidence) come from
the geometric fit through the slices (`fit_pipes`), not from the dense cloud. The fit needs what the
slices still have and the dense cloud has lost — which points lie on which survey line — and its axis
and radius are what a user measures against; GPRNet's contribution is the dense cloud itself (bends,
tees, gaps from missing lines), whose points are labelled with the nearest fitted pipe for colouring.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from gprbot.config import ReconstructionConfig
from gprbot.errors import InterpretationError, ModelError
from gprbot.geometry import distance_to_polyline
from gprbot.infer.onnx_model import OnnxModel
from gprbot.reconstruct.completion import PipeModel, Reconstruction, fit_pipes
from gprbot.reconstruct.register import SliceCloud, resample_cloud

INPUT_NAME = "sparse_points"  # the names tools/export_onnx.py gives completion models
OUTPUT_NAME = "dense_points"
SPARSE_POINTS = 1500
MIN_SCALE_M = 1e-3


def normalisation(sparse_m: NDArray[np.floating]) -> tuple[NDArray[np.float64], float]:
    """Centre (3,) and scale of the unit-cube normalisation, from the sparse cloud (metres) alone."""
    lo, hi = np.min(sparse_m, axis=0), np.max(sparse_m, axis=0)
    return np.asarray(0.5 * (lo + hi), dtype=np.float64), float(max(np.max(hi - lo), MIN_SCALE_M))


class GprnetCompletion:
    """A loaded completion model (GPRNet, or PCN / PF-Net with the same contract) and its last timing."""

    def __init__(self, model_path: Path, threads: int = 2, *, expect_name: str | None = None) -> None:
        self.model = OnnxModel(Path(model_path), threads=threads, expect_name=expect_name)
        names_in = [s.name for s in self.model.inputs]
        names_out = [s.name for s in self.model.outputs]
        if names_in != [INPUT_NAME] or OUTPUT_NAME not in names_out:
            raise ModelError(
                f"{model_path}: a completion model takes {INPUT_NAME!r} and gives {OUTPUT_NAME!r}, this one takes "
                f"{names_in} and gives {names_out}; re-export it with tools/export_onnx.py"
            )
        self.last_seconds = 0.0

    def complete(self, sparse_points: NDArray[np.floating]) -> NDArray[np.float64]:
        """Sparse cloud (1500, 3) in metres → dense cloud (N, 3) in metres."""
        sparse = np.asarray(sparse_points, dtype=np.float64)
        if sparse.shape != (SPARSE_POINTS, 3) or not np.all(np.isfinite(sparse)):
            raise InterpretationError(
                f"GPRNet needs a finite sparse cloud of shape ({SPARSE_POINTS}, 3), got {sparse.shape}; "
                f"resample the registered slices with reconstruction.sparse_points: {SPARSE_POINTS}"
            )
        centre, scale = normalisation(sparse)
        x = ((sparse - centre) / scale).astype(np.float32)[None]
        outputs, self.last_seconds = self.model.run({INPUT_NAME: x})
        dense = np.asarray(outputs[OUTPUT_NAME], dtype=np.float64)[0]
        return np.asarray(dense * scale + centre, dtype=np.float64)


def nearest_pipe_labels(points: NDArray[np.float64], pipes: Sequence[PipeModel]) -> NDArray[np.intp]:
    """For every point, the index of the pipe whose axis is nearest (0 for all when there is no pipe)."""
    if not pipes or len(points) == 0:
        return np.zeros(len(points), dtype=np.intp)
    distances = np.stack([distance_to_polyline(points, p.axis) - p.radius_m for p in pipes], axis=1)
    return np.asarray(np.argmin(distances, axis=1), dtype=np.intp)


def gprnet_reconstruction(
    slices: Sequence[SliceCloud],
    sparse_m: NDArray[np.float64],
    cfg: ReconstructionConfig,
    completion: GprnetCompletion,
    rng: np.random.Generator,
) -> Reconstruction:
    """Pipes from the geometric fit through the slices; the dense cloud from GPRNet on the sparse cloud."""
    if len(sparse_m) == 0:
        return Reconstruction(pipes=(), dense=np.zeros((0, 3)), labels=np.zeros(0, dtype=np.intp))
    sparse = sparse_m if len(sparse_m) == SPARSE_POINTS else resample_cloud(sparse_m, SPARSE_POINTS, rng)
    pipes = tuple(fit_pipes(slices, cfg))
    dense = completion.complete(sparse)
    return Reconstruction(pipes=pipes, dense=dense, labels=nearest_pipe_labels(dense, pipes))
