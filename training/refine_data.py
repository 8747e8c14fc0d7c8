"""Dataset of the fit-conditioned completion: interpreted B-scans → geometric fit → what the truth says of it.

    python -m training.refine_data train val --limit 900   # caches training/cache/refine_<split>_<version>.npz

Per random scene (training.random_scenes) every kept line is simulated and *interpreted* (the classical
chain and MigrationNet on alternate runs of six seeds, so each case sees both), so the fit sees the false
pipes, merged sections, broken tracks and biased radii that the product's interpreters really give —
the degraded truth masks of training.pointcloud_data have none of the false pipes that rebar and clutter
make. One shortcut, stated: the velocity is the true one times (1 + N(0, VELOCITY_JITTER)) rather than
the survey's estimate, which costs ~3 s a scene (the end-to-end evaluation estimates it; its median
error there is under 1 %).

A sample holds, normalised to the sparse cloud's unit cube (gprbot.infer.gprnet.normalisation): the
sparse cloud (1500); FIT_POINTS points inside the fitted rods with their pipe index (the network's view
of the fit); QUERY_POINTS points inside the rods pushed on to the survey's edge
(gprbot.reconstruct.extension), each with its pipe, how far past the fitted part it lies, and whether it
lies inside a true pipe (the label); and the dense truth (8192). MigrationNet was trained on these
training scenes, so on them it is better than on unseen ones: half the training set is kinder than the field.
"""

from __future__ import annotations

import argparse
import multiprocessing
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from gprbot.config import Config, ReconstructionConfig, load_config
from gprbot.errors import GprbotError
from gprbot.geometry import distance_to_polyline
from gprbot.gpr.preprocess import preprocess
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.infer.gprnet import normalisation
from gprbot.infer.pipeline import line_section
from gprbot.motion.planner import survey_region
from gprbot.progress import track
from gprbot.reconstruct.completion import fit_pipes
from gprbot.reconstruct.extension import Footprint, rod_candidates, survey_footprint
from gprbot.reconstruct.register import SliceCloud, register_slice, resample_cloud
from gprbot.sim.scene import Scene
from gprbot.sim.truth import sample_pipe_interiors
from training.code_version import code_version
from training.migration_data import simulate_line
from training.random_scenes import CASES, SPLIT_SIZES, SurveySpec, gpr_config, scene_for_seed, split_seeds

ROOT = Path(__file__).resolve().parents[1]
CACHE_DIR = ROOT / "training" / "cache"
SPARSE_POINTS = 1500
FIT_POINTS = 2048  # the runtime feeds 1024; training draws them from these
QUERY_POINTS = 4096
DENSE_POINTS = 8192
VELOCITY_JITTER = 0.012  # σ of the relative velocity error (the end-to-end estimate's median |error| is 0.8 %)
INSIDE_MARGIN_M = 0.015  # a rod point within a true pipe's radius + this lies inside it (the fit's radii are ±10 %)
Method = Literal["classical", "migrationnet"]
_RNG_TAG = 0x52464E  # separates this module's draws from the scene's
# The files whose code makes the samples: change one and the cache is rebuilt.
_SOURCES = ("training/refine_data.py", "training/random_scenes.py", "training/migration_data.py", "gprbot/sim",
            "gprbot/gpr", "gprbot/reconstruct", "gprbot/infer/migrationnet.py", "models/migrationnet.onnx")


@dataclass(frozen=True)
class RefineSample:
    """One interpreted survey: sparse cloud, fitted-rod points, extended-rod query points and labels, truth."""

    seed: int
    case: str
    method: str
    sparse: NDArray[np.float32]  # (SPARSE_POINTS, 3)
    fit: NDArray[np.float32]  # (FIT_POINTS, 3)
    fit_pipe: NDArray[np.int64]  # (FIT_POINTS,) fitted pipe of each point
    query: NDArray[np.float32]  # (QUERY_POINTS, 3)
    query_pipe: NDArray[np.int64]
    beyond: NDArray[np.float32]  # (QUERY_POINTS,) distance past the fitted part, normalised (0 inside it)
    inside: NDArray[np.float32]  # (QUERY_POINTS,) 1 inside a true pipe
    dense: NDArray[np.float32]  # (DENSE_POINTS, 3)
    centre: NDArray[np.float64]
    scale: float


def data_version() -> str:
    """The cache key: training.code_version over the sources that make the samples.

    An explicit list rather than the import closure of this module: that closure runs through
    gprbot.infer.pipeline into the runtime of the refiner itself, whose edits do not change a sample.
    """
    files = [f for name in _SOURCES for f in
             (sorted((ROOT / name).rglob("*.py")) if (ROOT / name).is_dir() else [ROOT / name])]
    return code_version((), files)


def interpreted_slices(scene: Scene, spec: SurveySpec, method: Method, rng: np.random.Generator,
                       base: Config) -> tuple[list[SliceCloud], Footprint]:
    """Every kept line simulated, preprocessed, interpreted by `method` and registered at its recorded
    positions; and the footprint those positions cover."""
    gpr = replace(gpr_config(spec, scene, base.gpr), eps_r=None)
    cfg = replace(base, gpr=gpr, interpretation=replace(base.interpretation, method=method))
    velocity = velocity_from_eps(scene.slab.eps_r) * (1.0 + VELOCITY_JITTER * float(rng.standard_normal()))
    slices, positions = [], {}
    for line in spec.kept_lines():
        processed = preprocess(simulate_line(scene, spec, line, rng), cfg.gpr)
        section = line_section(processed, cfg, velocity)
        slices.append(register_slice(line, section.mask, section.z_m, processed.position_at(section.x_m)))
        positions[line] = processed.positions
    return slices, survey_footprint(positions)


def inside_truth(points: NDArray[np.float64], scene: Scene) -> NDArray[np.float32]:
    """1 for each point within a true pipe's radius + INSIDE_MARGIN_M of its axis, else 0."""
    inside = np.zeros(len(points), dtype=bool)
    for pipe in scene.pipes:
        inside |= distance_to_polyline(points, pipe.points) <= pipe.radius_m + INSIDE_MARGIN_M
    return inside.astype(np.float32)


def make_sample(seed: int, base: Config) -> RefineSample | None:
    """The sample of a split seed, or None when the interpreters refused it or no pipe was fitted."""
    scene, spec = scene_for_seed(seed)
    method: Method = "classical" if (seed // len(CASES)) % 2 == 0 else "migrationnet"  # every case sees both
    rng = np.random.default_rng([seed, _RNG_TAG])
    try:
        slices, footprint = interpreted_slices(scene, spec, method, rng, base)
    except GprbotError:
        return None
    points = np.concatenate([s.points for s in slices])
    pipes = fit_pipes(slices, ReconstructionConfig()) if len(points) else []
    if not pipes:
        return None
    sparse = resample_cloud(points, SPARSE_POINTS, rng)
    candidates = rod_candidates(pipes, footprint, FIT_POINTS, QUERY_POINTS, rng, slices)
    if candidates is None:
        return None
    half = 0.5 * spec.spacing_m
    region = survey_region(spec.start_xy, spec.length_m, spec.lines, spec.spacing_m, across_margin_m=half)
    try:
        dense, _ = sample_pipe_interiors(scene, DENSE_POINTS, rng, region)
    except GprbotError:
        return None
    centre, scale = normalisation(sparse)

    def unit(x: NDArray[np.float64]) -> NDArray[np.float32]:
        return ((x - centre) / scale).astype(np.float32)

    return RefineSample(seed, CASES[seed % len(CASES)], method, unit(sparse), unit(candidates.fit),
                        candidates.fit_pipe, unit(candidates.query), candidates.query_pipe,
                        (candidates.beyond_m / scale).astype(np.float32), inside_truth(candidates.query, scene),
                        unit(dense), centre, scale)


def _sample_of(seed: int) -> RefineSample | None:
    base = load_config()  # one thread per worker process: the pool is the parallelism
    return make_sample(seed, replace(base, reconstruction=replace(base.reconstruction, model_threads=1)))


def cache_path(split: str, limit: int | None) -> Path:
    """Where a split's arrays are cached (keyed on the code version and the sample count)."""
    whole = limit is None or limit >= SPLIT_SIZES[split]
    return CACHE_DIR / f"refine_{split}_{data_version()}{'' if whole else f'_n{limit}'}.npz"


def build_split(split: str, limit: int | None = None, workers: int = 1) -> dict[str, NDArray[np.generic]]:
    """Every sample of a split (or its first `limit` seeds) as stacked arrays, cached."""
    path = cache_path(split, limit)
    if path.exists():
        with np.load(path) as data:
            return {k: data[k] for k in data.files}
    seeds = list(split_seeds(split))[:limit]  # type: ignore[arg-type]
    with multiprocessing.get_context("spawn").Pool(workers) as pool:
        made = list(track(pool.imap(_sample_of, seeds, chunksize=4), f"{split} samples", total=len(seeds),
                          unit="scene"))
    samples = [s for s in made if s is not None]
    arrays = {
        "seed": np.array([s.seed for s in samples]), "case": np.array([s.case for s in samples]),
        "method": np.array([s.method for s in samples]),
        **{key: np.stack([getattr(s, key) for s in samples])
           for key in ("sparse", "fit", "fit_pipe", "query", "query_pipe", "beyond", "inside", "dense")},
        "centre": np.stack([s.centre for s in samples]), "scale": np.array([s.scale for s in samples]),
        "skipped": np.array(sorted(set(seeds) - {s.seed for s in samples})),
    }
    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial.npz")
    np.savez(partial, **arrays)  # type: ignore[arg-type]
    partial.replace(path)
    return arrays


def main() -> None:
    """Generate and cache the named splits, printing their size and time."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("splits", nargs="*", default=["train", "val"])
    parser.add_argument("--limit", type=int, default=None, help="only the first N seeds of each split")
    parser.add_argument("--workers", type=int, default=2, help="processes (the samples do not depend on it)")
    args = parser.parse_args()
    for split in args.splits:
        start = time.perf_counter()
        arrays = build_split(split, args.limit, args.workers)
        past = np.asarray(arrays["beyond"], dtype=np.float64) > 0
        print(f"{split}: {len(arrays['seed'])} samples ({len(arrays['skipped'])} skipped) in "
              f"{time.perf_counter() - start:.0f} s; query points inside a true pipe: "
              f"{arrays['inside'][~past].mean():.2f} on the fitted parts, {arrays['inside'][past].mean():.2f} past "
              f"them ({past.mean():.2f} of the points)", flush=True)


if __name__ == "__main__":
    main()
