"""MigrationNet at run time: a B-scan → the filled cross-section mask and pipe detections, via ONNX.

The network sees the B-scan converted from time to depth with the survey velocity (straight-down
two-way time with the antenna's height and Tx–Rx offset) on a fixed grid: DX_M along track, DZ_M in
depth, ROWS deep. In depth coordinates a point diffractor's hyperbola is z(x) = sqrt(z0² + (x-x0)²)
whatever the permittivity, so the network learns one geometric focusing instead of one per velocity.
The line is cut into COLS-wide tiles overlapping by half, run as one batch, and the probabilities
are stitched with a triangular weight. Detections are the mask's blobs.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from gprbot.config import GprConfig, InterpretationConfig, model_path
from gprbot.errors import ModelError
from gprbot.gpr.bscan import BScan, CrossSection, Detection, check_bscan
from gprbot.gpr.interpret import resolve_velocity
from gprbot.gpr.migration import diffraction_times, resample_uniform
from gprbot.gpr.preprocess import preprocess
from gprbot.infer.onnx_model import OnnxModel

FloatArray = NDArray[np.float64]
Float32Array = NDArray[np.float32]

DX_M = 0.01  # along-track pixel (m)
ROWS = 128
COLS = 128
DEPTH_M = 0.6  # depth covered by the ROWS rows
DZ_M = DEPTH_M / ROWS
CLIP = 5.0  # normalised amplitudes are clipped to ±CLIP
_SCALE_PERCENTILE = 99.5
_MIN_BLOB_PIXELS = 4
INPUT_NAME = "bscan_depth"
OUTPUT_NAME = "pipe_probability"


def default_model_path() -> Path:
    """models/migrationnet.onnx of this checkout (the model shipped with the code)."""
    return model_path(InterpretationConfig().migrationnet_model)


def depth_grid() -> FloatArray:
    """Depths (m, positive down) of the network's rows: pixel centres."""
    return (np.arange(ROWS, dtype=np.float64) + 0.5) * DZ_M


def depth_section(bscan: BScan, gpr: GprConfig, velocity_m_per_ns: float) -> tuple[Float32Array, FloatArray]:
    """The preprocessed line resampled to (ROWS, nx) in depth, normalised; and the along-track x (nx,).

    Amplitudes are divided by the line's 99.5th percentile of |a| and clipped to ±CLIP, so the
    network sees the same scale whatever the antenna's gain.
    """
    pre = preprocess(bscan, gpr)
    data, x = resample_uniform(pre, DX_M)
    z = depth_grid()
    t_ns = diffraction_times(np.zeros(1), z, velocity_m_per_ns, gpr.antenna_height_m, gpr.tx_rx_offset_m)[0]
    position = (t_ns + pre.t0_ns) / pre.dt_ns
    samples_per_row = float(np.median(np.diff(position)))
    if samples_per_row > 1.0:  # anti-alias before taking one sample per row
        data = ndimage.gaussian_filter1d(data, 0.5 * samples_per_row, axis=1, mode="nearest")
    n_samples = data.shape[1]
    lo = np.clip(np.floor(position).astype(np.intp), 0, n_samples - 1)
    hi = np.clip(lo + 1, 0, n_samples - 1)
    frac = np.clip(position - lo, 0.0, 1.0)
    image = data[:, lo] * (1.0 - frac) + data[:, hi] * frac  # (nx, ROWS)
    image[:, position > n_samples - 1] = 0.0
    scale = float(np.percentile(np.abs(image), _SCALE_PERCENTILE))
    image = np.clip(image / max(scale, 1e-9), -CLIP, CLIP) if scale > 0 else np.zeros_like(image)
    return np.ascontiguousarray(image.T, dtype=np.float32), x


def tile_starts(n_columns: int, stride: int = COLS // 2) -> list[int]:
    """First column of each COLS-wide tile: every `stride`, the last one flush with the line's end."""
    if n_columns <= COLS:
        return [0]
    starts = list(range(0, n_columns - COLS, stride))
    return [*starts, n_columns - COLS]


def cut_tiles(image: Float32Array) -> tuple[Float32Array, list[int]]:
    """(n_tiles, 1, ROWS, COLS) tiles of a (ROWS, nx) image, zero-padded on the right if shorter."""
    n = image.shape[1]
    padded = image if n >= COLS else np.pad(image, ((0, 0), (0, COLS - n)))
    starts = tile_starts(n)
    return np.stack([padded[None, :, s:s + COLS] for s in starts]).astype(np.float32), starts


def stitch(probabilities: Float32Array, starts: list[int], n_columns: int) -> Float32Array:
    """Blend overlapping tile outputs (n_tiles, 1, ROWS, COLS) into (ROWS, n_columns), tile edges weighted down."""
    width = max(n_columns, COLS)
    total = np.zeros((ROWS, width))
    weight = np.zeros(width)
    ramp = np.minimum(np.arange(COLS) + 1.0, COLS - np.arange(COLS)).astype(np.float64)
    for tile, s in zip(probabilities, starts, strict=True):
        total[:, s:s + COLS] += tile[0] * ramp
        weight[s:s + COLS] += ramp
    return np.asarray((total / weight)[:, :n_columns], dtype=np.float32)


def blobs_to_detections(probability: Float32Array, x_m: FloatArray, z_m: FloatArray, threshold: float = 0.5,
                        min_peak: float = 0.0) -> tuple[NDArray[np.bool_], tuple[Detection, ...]]:
    """Threshold the probabilities; each connected blob is a pipe: centroid, half its height, peak probability.

    A blob whose peak stays under `min_peak` (the card's, from the validation split) leaves the mask too: the
    network is unsure of what it has not been trained on (clutter on real field lines peaked at 0.54-0.68,
    true pipes on the FDTD dev half at 0.90-1.00).
    """
    mask = probability >= threshold
    labels, _ = ndimage.label(mask)
    detections: list[Detection] = []
    for index, region in enumerate(ndimage.find_objects(labels), start=1):
        if region is None:
            continue
        inside = labels[region] == index
        p = probability[region][inside].astype(np.float64)
        if inside.sum() < _MIN_BLOB_PIXELS or p.max() < min_peak:
            mask[region][inside] = False
            continue
        rows, cols = np.nonzero(inside)
        z = z_m[region[0]][rows]
        x = x_m[region[1]][cols]
        height = float(z.max() - z.min()) + (z_m[1] - z_m[0])
        # The blob's half-height is no measurement of the radius (it regresses to 2.5-3 cm: validation/README.md),
        # so the detection says where its radius comes from, as the chain's mask-sized pipes do.
        detections.append(Detection(float(np.average(x, weights=p)), float(np.average(z, weights=p)),
                                    height / 2.0, float(p.max()), radius_from_mask=True))
    return mask, tuple(sorted(detections, key=lambda d: d.x_m))


class MigrationNetInterpreter:
    """Interprets B-scans with the MigrationNet ONNX model; same CrossSection as the classical path."""

    def __init__(self, model_path: Path | None = None, threads: int = 2) -> None:
        model_path = default_model_path() if model_path is None else Path(model_path)
        self.model = OnnxModel(model_path, threads=threads, expect_name="migrationnet")
        grid = self.model.card.get("grid", {})
        expected = {"dx_m": DX_M, "dz_m": DZ_M, "rows": ROWS, "cols": COLS, "clip": CLIP}
        if any(not math.isclose(float(grid.get(k, math.nan)), v) for k, v in expected.items()):
            raise ModelError(
                f"{model_path}: its card's grid {grid} differs from this gprbot's {expected}; "
                "re-export the model with tools/export_onnx.py from this version"
            )

    @property
    def threshold(self) -> float:
        """The probability above which a pixel is pipe: calibrated on the validation split, from the card."""
        return float(self.model.card.get("threshold", 0.5))

    @property
    def min_peak(self) -> float:
        """The least peak probability of a blob kept as a pipe: calibrated on the validation split, from the card."""
        return float(self.model.card.get("min_peak", 0.0))

    def probabilities(self, image: Float32Array) -> Float32Array:
        """Pipe probability (ROWS, nx) of a depth section (ROWS, nx): the mean of the network's answers for the line
        and for the line read backwards.

        A common-offset line driven the other way is the same physics (Tx and Rx swap, the times do not), so a blob
        that only one direction shows is the network's, not the data's. FDTD training batch (out of sample), velocity
        given: false pipes 14 -> 10 on 40 scenes, within 3 cm 22 of 45 either way (validation/README.md).
        """
        mirrored = self._one_way(np.ascontiguousarray(image[:, ::-1]))[:, ::-1]
        return np.asarray(0.5 * (self._one_way(image) + mirrored), dtype=np.float32)

    def _one_way(self, image: Float32Array) -> Float32Array:
        """The network's pipe probability for the section as given."""
        tiles, starts = cut_tiles(image)
        outputs, _ = self.model.run({INPUT_NAME: tiles})
        return stitch(np.asarray(outputs[OUTPUT_NAME], dtype=np.float32), starts, image.shape[1])

    def interpret(self, bscan: BScan, gpr: GprConfig, cfg: InterpretationConfig,
                  velocity: float | None = None) -> CrossSection:
        """One B-scan → depth image, pipe mask (probability ≥ the card's threshold), detections (score ≥ min_score)."""
        check_bscan(bscan)
        v, estimated = resolve_velocity(bscan, gpr, cfg, velocity)
        image, x = depth_section(bscan, gpr, v)
        z = depth_grid()
        probability = self.probabilities(image)
        mask, detections = blobs_to_detections(probability, x, z, self.threshold, self.min_peak)
        kept = tuple(d for d in detections if d.score >= cfg.min_score)
        return CrossSection(mask, x, z, image, kept, v, estimated)
