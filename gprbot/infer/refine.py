"""The fit-conditioned completion at run time: the geometric fit, continued, judged and corrected by the FitRefiner.

1. The geometric fit through the slices gives pipes (axes, radii) as always.
2. Each pipe's free ends are pushed on to the survey's edge (gprbot.reconstruct.extension); points are
   sampled inside these longer rods.
3. The network (ONNX) sees the sparse cloud and points of the fitted rods, and says for every candidate
   point whether it lies inside a real pipe, and by how much to move it (the interpreter's radius and
   depth biases). A pipe whose fitted part scores below the model's pipe threshold (its card's, chosen on the
   validation surveys) is dropped as false; along a kept one, the accepted points may reach past where the
   fit stopped (the pipe goes on).
4. The dense cloud is cfg.dense_points of the accepted, moved points.

Without a model (completion "extended") every candidate is accepted and none is moved: the fit pushed on
to the survey's edge by rule — the baseline that says how much of the refiner's gain is the network's.
Measured (models/README.md, training.refine_parts): the shipped models accept every candidate too, so their
whole effect is the offsets.

pipes.json gets the kept pipes, each axis cut to the span of its accepted points and its confidence the
mean probability over its fitted part, and `inferred_m` how much of it at each end no line saw. Axes
and radii are the fit's (axes cut or continued; the corrections move cloud points only).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from gprbot.config import ReconstructionConfig
from gprbot.errors import InterpretationError, ModelError
from gprbot.geometry import polyline_length
from gprbot.infer.gprnet import normalisation
from gprbot.infer.onnx_model import OnnxModel
from gprbot.reconstruct.completion import Reconstruction, fit_pipes
from gprbot.reconstruct.extension import Footprint, arclength_on, cut_polyline, rod_candidates
from gprbot.reconstruct.register import SliceCloud, resample_cloud

SPARSE_NAME, FIT_NAME, FIT_PIPES_NAME = "sparse_points", "fit_points", "fit_pipes"
QUERY_NAME, QUERY_PIPES_NAME, BEYOND_NAME = "query_points", "query_pipes", "query_beyond"
LOGITS_NAME, REFINED_NAME = "point_logits", "refined_points"
SPARSE_POINTS = 1500
FIT_POINTS = 1024
QUERY_POINTS = 16384  # candidates; about half are accepted on a typical survey, cfg.dense_points are kept
MAX_PIPES = 12  # pipes with their own column; points of further pipes see no pipe feature (rows of zeros)
ACCEPT = 0.5  # a point is accepted at this probability, a pipe when this share of its fitted part is


def onehot(owner: NDArray[np.integer], n_columns: int = MAX_PIPES) -> NDArray[np.float32]:
    """Pipe index per point → (N, MAX_PIPES) one-hot; indices ≥ MAX_PIPES give a row of zeros."""
    out = np.zeros((len(owner), n_columns), dtype=np.float32)
    gated = np.flatnonzero(owner < n_columns)
    out[gated, owner[gated]] = 1.0
    return out


class FitRefinerModel:
    """A loaded FitRefiner and its last inference time."""

    def __init__(self, model_path: Path, threads: int = 2) -> None:
        self.model = OnnxModel(Path(model_path), threads=threads, expect_name="fit_refiner")
        names = [s.name for s in self.model.inputs]
        expected = [SPARSE_NAME, FIT_NAME, FIT_PIPES_NAME, QUERY_NAME, QUERY_PIPES_NAME, BEYOND_NAME]
        if names != expected:
            raise ModelError(f"{model_path}: not a FitRefiner (inputs {names}, expected {expected}); "
                             "re-export it with tools/export_onnx.py fit_refiner")
        # Below this score a fitted pipe is dropped as false: chosen per model on the validation surveys
        # (training.refine_pipe_threshold); a card without one keeps every pipe most of whose fit it accepts.
        self.pipe_threshold = float(self.model.card.get("pipe_threshold", ACCEPT))
        self.last_seconds = 0.0

    def run(self, sparse: NDArray[np.float32], fit: NDArray[np.float32], fit_pipes: NDArray[np.float32],
            query: NDArray[np.float32], query_pipes: NDArray[np.float32],
            beyond: NDArray[np.float32]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """One pass in the normalised frame: acceptance probability (Q,) and moved query points (Q, 3)."""
        feeds = {SPARSE_NAME: sparse, FIT_NAME: fit, FIT_PIPES_NAME: fit_pipes, QUERY_NAME: query,
                 QUERY_PIPES_NAME: query_pipes, BEYOND_NAME: beyond[:, None]}
        batch = {k: np.asarray(v, dtype=np.float32)[None] for k, v in feeds.items()}
        outputs, self.last_seconds = self.model.run(batch)
        logits = np.asarray(outputs[LOGITS_NAME], dtype=np.float64)[0]
        return 1.0 / (1.0 + np.exp(-logits)), np.asarray(outputs[REFINED_NAME], dtype=np.float64)[0]


def pipe_scores(probability: NDArray[np.float64], owner: NDArray[np.int64], beyond: NDArray[np.float64],
                n_pipes: int) -> list[float]:
    """Each fitted pipe's score: the mean probability over the candidates inside its fitted part (0: none)."""
    inside_fit = beyond <= 0.0
    return [float(np.mean(probability[(owner == k) & inside_fit])) if np.any((owner == k) & inside_fit) else 0.0
            for k in range(n_pipes)]


def accepted(probability: NDArray[np.float64], owner: NDArray[np.int64], beyond: NDArray[np.float64],
             n_pipes: int, pipe_threshold: float = ACCEPT) -> tuple[NDArray[np.bool_], list[int]]:
    """The accepted points and the kept pipes (score at least pipe_threshold; at least the likeliest pipe)."""
    inside_fit = beyond <= 0.0
    scores = pipe_scores(probability, owner, beyond, n_pipes)
    kept = [k for k in range(n_pipes) if scores[k] >= pipe_threshold] or [int(np.argmax(scores))]
    points = (probability >= ACCEPT) & np.isin(owner, kept)
    if not points.any():  # the likeliest pipe's fitted part stands, as the fit drew it
        points = np.isin(owner, kept) & inside_fit
    return points, kept


def refined_reconstruction(
    slices: Sequence[SliceCloud], sparse_m: NDArray[np.float64], footprint: Footprint, cfg: ReconstructionConfig,
    model: FitRefinerModel | None, rng: np.random.Generator,
) -> Reconstruction:
    """The fit's pipes continued, pruned and corrected by the network (None: continued by rule); the cloud in them."""
    pipes = fit_pipes(slices, cfg)
    if not pipes or len(sparse_m) == 0:
        return Reconstruction(pipes=(), dense=np.zeros((0, 3)), labels=np.zeros(0, dtype=np.intp))
    sparse = sparse_m if len(sparse_m) == SPARSE_POINTS else resample_cloud(sparse_m, SPARSE_POINTS, rng)
    if not np.all(np.isfinite(sparse)):
        raise InterpretationError("the sparse cloud has non-finite points; check the registered slices")
    candidates = rod_candidates(pipes, footprint, FIT_POINTS, QUERY_POINTS, rng, slices)
    if candidates is None:
        raise InterpretationError(f"no fitted pipe lies inside the survey's footprint {footprint}; check the "
                                  "recorded positions of the lines")
    centre, scale = normalisation(sparse)

    def unit(x: NDArray[np.float64]) -> NDArray[np.float32]:
        return ((x - centre) / scale).astype(np.float32)

    if model is None:
        probability, moved = np.ones(len(candidates.query)), unit(candidates.query).astype(np.float64)
    else:
        probability, moved = model.run(unit(sparse), unit(candidates.fit), onehot(candidates.fit_pipe),
                                       unit(candidates.query), onehot(candidates.query_pipe),
                                       (candidates.beyond_m / scale).astype(np.float32))
    points, kept = accepted(probability, candidates.query_pipe, candidates.beyond_m, len(pipes),
                            ACCEPT if model is None else model.pipe_threshold)
    new_index = {old: new for new, old in enumerate(kept)}
    chosen = []
    for k in kept:
        mine = points & (candidates.query_pipe == k)
        axis, added = candidates.extended[k].axis, candidates.extended[k].added
        span = arclength_on(candidates.query[mine], axis) if mine.any() else np.array([0.0])
        total = polyline_length(axis)
        inferred = (max(0.0, added[0] - float(span.min())), max(0.0, float(span.max()) - (total - added[1])))
        fitted = (candidates.query_pipe == k) & (candidates.beyond_m <= 0.0)
        ends = tuple(None if e is None else new_index.get(e) for e in pipes[k].ends_on)
        cut = cut_polyline(axis, float(span.min()), float(span.max()))
        # The radius stays the fit's: re-measured from the corrected points (R = √(2·mean d²)) it came out
        # worse end to end (median |diameter error| 16 % against the fit's 11 %, classical, 60 simulated surveys).
        chosen.append(replace(pipes[k], axis=cut, depth_of_cover_m=float(np.min(-cut[:, 2])) - pipes[k].radius_m,
                              confidence=float(np.mean(probability[fitted])) if fitted.any() else 0.0,
                              ends_on=(ends[0], ends[1]), inferred_m=inferred))
    pick = rng.choice(np.flatnonzero(points), size=cfg.dense_points,
                      replace=int(points.sum()) < cfg.dense_points)
    dense = moved[pick] * scale + centre
    labels = np.array([new_index[int(k)] for k in candidates.query_pipe[pick]], dtype=np.intp)
    return Reconstruction(pipes=tuple(chosen), dense=dense, labels=labels)
