"""Completion dataset: sparse registered slices (1500 points) → dense truth inside the pipes (8192 points).

Per random scene (training.random_scenes): every kept survey line's truth cross-section mask at the
line's true antenna columns, degraded like a real interpreter's output (erosion/dilation, dropped blobs,
speckle, a survey-wide depth-scale error from a wrong velocity), registered in 3D at the *recorded*
(noisy) positions → resampled to 1500 points. The truth is 8192 points sampled uniformly inside the
solid pipes over the surveyed rectangle (lines ± half a spacing, the geometric completion's extent).
Each sample is normalised to the unit cube from its sparse cloud alone (as the runtime must):
`normalised = (metres − centre) / scale`, centre = the sparse bounding box's centre, scale = its longest
side (gprbot.infer.gprnet.normalisation, shared with the runtime). Generated once per split and
cached under training/cache/.
"""

from __future__ import annotations

import argparse
import multiprocessing
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from gprbot.errors import ConfigError
from gprbot.infer.gprnet import normalisation
from gprbot.motion.planner import survey_region
from gprbot.progress import track
from gprbot.reconstruct.register import SliceCloud, register_slice, resample_cloud
from gprbot.sim.truth import cross_section_mask, sample_pipe_interiors
from training.random_scenes import CASES, line_antenna_xy, recorded_positions, scene_for_seed, split_seeds

CACHE_DIR = Path(__file__).resolve().parent / "cache"
SPARSE_POINTS = 1500
DENSE_POINTS = 8192
DEPTH_PITCH_M = 0.005  # mask row pitch (the runtime's masks are ~5 mm in depth and along-track)
TRACE_PITCH_M = 0.005
_RNG_TAG = 0x47505231  # separates this module's draws from the scene's


@dataclass(frozen=True)
class CompletionSample:
    """One survey: sparse and dense clouds (normalised), the normalisation and the scene's case."""

    seed: int
    case: str
    sparse: NDArray[np.float32]
    dense: NDArray[np.float32]
    centre: NDArray[np.float64]
    scale: float


def degrade_mask(mask: NDArray[np.bool_], rng: np.random.Generator) -> NDArray[np.bool_]:
    """Make a truth mask look like an interpreter's: ±1-pixel edges, a dropped blob, speckle."""
    out = mask.copy()
    u = rng.random()
    if u < 0.2:
        out = ndimage.binary_erosion(out, iterations=1) if out.sum() > 40 else out
    elif u < 0.4:
        out = ndimage.binary_dilation(out, iterations=1)
    labels, count = ndimage.label(out)
    for blob in range(1, count + 1):
        if rng.random() < 0.05:
            out[labels == blob] = False
    if rng.random() < 0.08:  # false positives: a small blob somewhere in the section
        for _ in range(int(rng.integers(1, 3))):
            iz, ix = int(rng.integers(out.shape[0])), int(rng.integers(out.shape[1]))
            r = int(rng.integers(1, 3))
            out[max(iz - r, 0) : iz + r + 1, max(ix - r, 0) : ix + r + 1] = True
    return out


def survey_slices(seed: int, *, degrade: bool = True) -> tuple[list[SliceCloud], tuple[float, float, float, float]]:
    """The registered slices of a split seed's survey and the surveyed rectangle (xmin, xmax, ymin, ymax)."""
    scene, spec = scene_for_seed(seed)
    rng = np.random.default_rng([seed, _RNG_TAG])
    z = np.arange(0.0, scene.slab.thickness_m, DEPTH_PITCH_M)
    depth_scale = float(rng.normal(1.0, 0.03)) if degrade else 1.0  # a velocity error of ~3 %
    slices = []
    for line in spec.kept_lines():
        true_xy = line_antenna_xy(spec, line, TRACE_PITCH_M)
        mask = cross_section_mask(scene, true_xy, z)
        if degrade:
            mask = degrade_mask(mask, rng)
        slices.append(register_slice(line, mask, z * depth_scale, recorded_positions(true_xy, spec, rng)))
    half = 0.5 * spec.spacing_m
    region = survey_region(spec.start_xy, spec.length_m, spec.lines, spec.spacing_m, across_margin_m=half)
    return slices, region


def make_sample(seed: int) -> CompletionSample | None:
    """The completion sample of a split seed, or None when no line saw a pipe."""
    scene, _ = scene_for_seed(seed)
    slices, region = survey_slices(seed)
    points = np.concatenate([s.points for s in slices])
    if len(points) == 0:
        return None
    rng = np.random.default_rng([seed, _RNG_TAG, 1])
    sparse = resample_cloud(points, SPARSE_POINTS, rng)
    try:
        dense, _ = sample_pipe_interiors(scene, DENSE_POINTS, rng, region)
    except ConfigError:
        return None
    centre, scale = normalisation(sparse)
    case = CASES[seed % len(CASES)]
    return CompletionSample(
        seed, case, ((sparse - centre) / scale).astype(np.float32), ((dense - centre) / scale).astype(np.float32),
        centre, scale,
    )


def cache_path(split: str) -> Path:
    """Where a split's arrays are cached."""
    return CACHE_DIR / f"completion_{split}.npz"


def build_split(split: str, limit: int | None = None, jobs: int = 1) -> dict[str, NDArray[np.generic]]:
    """Generate every sample of a split (optionally only the first `limit` seeds) as stacked arrays.

    Each sample depends on its seed alone, so `jobs` worker processes give the same arrays as one.
    """
    seeds = list(split_seeds(split))[:limit]  # type: ignore[arg-type]
    if jobs > 1:
        with multiprocessing.get_context("spawn").Pool(jobs) as pool:
            made = list(track(pool.imap(make_sample, seeds, chunksize=8), f"{split} samples", unit="sample",
                              total=len(seeds)))
    else:
        made = list(map(make_sample, track(seeds, f"{split} samples", unit="sample")))
    samples = [s for s in made if s is not None]
    return {
        "seed": np.array([s.seed for s in samples]),
        "case": np.array([s.case for s in samples]),
        "sparse": np.stack([s.sparse for s in samples]),
        "dense": np.stack([s.dense for s in samples]),
        "centre": np.stack([s.centre for s in samples]),
        "scale": np.array([s.scale for s in samples]),
    }


def load_split(split: str, *, generate: bool = True, jobs: int = 1) -> dict[str, NDArray[np.generic]]:
    """A split's arrays from the cache, generating and caching them first (in `jobs` processes) when missing."""
    path = cache_path(split)
    if not path.exists():
        if not generate:
            raise FileNotFoundError(f"{path} is missing; run `python -m training.pointcloud_data {split}`")
        arrays = build_split(split, jobs=jobs)
        CACHE_DIR.mkdir(parents=True, exist_ok=True)
        partial = path.with_suffix(".partial.npz")
        np.savez(partial, **arrays)  # type: ignore[arg-type]
        partial.replace(path)
    with np.load(path) as data:
        return {key: data[key] for key in data.files}


def main() -> None:
    """Generate and cache the named splits, printing their size and generation time."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("splits", nargs="*", default=["train", "val", "test"])
    parser.add_argument("--jobs", type=int, default=1, help="worker processes for the generation")
    args = parser.parse_args()
    for split in args.splits:
        start = time.perf_counter()
        arrays = load_split(split, jobs=args.jobs)
        cases = {c: int(np.sum(arrays["case"] == c)) for c in CASES}
        print(f"{split}: {len(arrays['seed'])} samples {cases} in {time.perf_counter() - start:.1f} s", flush=True)


if __name__ == "__main__":
    main()
