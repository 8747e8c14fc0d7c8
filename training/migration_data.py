"""MigrationNet's dataset: simulated survey lines of random scenes → (depth-section tile, true pipe mask).

For each scene of a split (training.random_scenes), a few of its survey lines are simulated with the
forward model at the true antenna positions, recorded with pose noise, preprocessed and converted to
depth exactly as at run time (gprbot.infer.migrationnet.depth_section), with the true velocity
perturbed by a few per cent in training (the survey velocity is an estimate). The train and val lines
are domain-randomised (gprbot.sim.variation: wavelet phase/peak, ringing, footprint, polarity, gain,
noise, clutter, antenna height; one draw per line from the scene's seed), the test lines are the default
simulator. The target is the true cross-section mask (gprbot.sim.truth) on the same grid. Tiles are
cached as .npz in training/cache/.

    python -m training.migration_data --split train   # ~1378 scenes × 4 lines × 1 tile
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, replace
from multiprocessing import Pool
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from gprbot.gpr.bscan import BScan
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.infer.migrationnet import cut_tiles, depth_grid, depth_section
from gprbot.progress import track
from gprbot.sim.forward import simulate_bscan
from gprbot.sim.scene import Clutter, Scene
from gprbot.sim.truth import cross_section_mask
from gprbot.sim.variation import DomainRandomisation, SignalVariation, varied_config
from training.random_scenes import (
    SurveySpec,
    gpr_config,
    line_antenna_xy,
    recorded_positions,
    scene_for_seed,
    split_seeds,
)

CACHE_DIR = Path(__file__).resolve().parent / "cache"
CACHE_VERSION = 2  # v2: calibrated simulator (issue 12 item 5) and domain randomisation of train/val
RANDOMISATION = DomainRandomisation()
LINES_PER_SCENE = 4
VELOCITY_JITTER = 0.03  # relative std of the velocity error in training
_TRACE_INTERVAL_S = 0.05


@dataclass(frozen=True)
class LineSample:
    """One simulated line: normalised depth section, true mask, along-track x, line index, velocity used."""

    image: NDArray[np.float32]
    mask: NDArray[np.bool_]
    x_m: NDArray[np.float64]
    line: int
    velocity_m_per_ns: float


def simulate_line(scene: Scene, spec: SurveySpec, line: int, rng: np.random.Generator,
                  variation: SignalVariation | None = None) -> BScan:
    """The raw B-scan of one survey line, positions as recorded (with pose noise)."""
    gpr = gpr_config(spec, scene)
    true_xy = line_antenna_xy(spec, line)
    data = simulate_bscan(scene, true_xy, gpr, rng, variation=variation)
    positions = recorded_positions(true_xy, spec, rng)
    times = np.arange(len(true_xy)) * _TRACE_INTERVAL_S
    return BScan(data, gpr.dt_ns, gpr.pre_trigger_ns, positions, times)


def line_sample(scene: Scene, spec: SurveySpec, line: int, rng: np.random.Generator,
                velocity_jitter: float = 0.0, variation: SignalVariation | None = None) -> LineSample:
    """Simulate one line and build its network input and true mask (interpreted at the variation's height)."""
    bscan = simulate_line(scene, spec, line, rng, variation)
    v = velocity_from_eps(scene.slab.eps_r) * (1.0 + velocity_jitter * float(rng.standard_normal()))
    gpr = gpr_config(spec, scene)
    image, x = depth_section(bscan, gpr if variation is None else varied_config(gpr, variation), v)
    columns = np.stack([spec.start_xy[0] + x, np.full(len(x), spec.line_y(line))], axis=1)
    mask = cross_section_mask(scene, columns, depth_grid())
    return LineSample(image, mask, x, line, v)


def scene_tiles(seed: int, split: str) -> tuple[NDArray[np.float16], NDArray[np.uint8]]:
    """Tiles (n, 1, ROWS, COLS) of up to LINES_PER_SCENE random lines of a scene, one random tile per line."""
    scene, spec = scene_for_seed(seed)
    rng = np.random.default_rng([seed, 1])
    kept = list(spec.kept_lines())
    lines = rng.choice(kept, size=min(LINES_PER_SCENE, len(kept)), replace=False)
    jitter = VELOCITY_JITTER if split == "train" else 0.0
    randomise = split != "test"
    dr = np.random.default_rng([seed, 2])  # its own stream: the scene's lines and tiles stay those of v1
    if randomise and scene.clutter is None and dr.random() < RANDOMISATION.clutter_probability:
        depth = (0.02, scene.slab.thickness_m - 0.02)
        clutter = Clutter(int(dr.integers(50, 300)), float(dr.uniform(0.004, 0.012)), depth, int(dr.integers(2**31)))
        scene = replace(scene, clutter=clutter)
    inputs, targets = [], []
    for line in sorted(int(i) for i in lines):
        variation = RANDOMISATION.draw(dr) if randomise else None
        sample = line_sample(scene, spec, line, rng, jitter, variation)
        tiles, starts = cut_tiles(sample.image)
        masks, _ = cut_tiles(sample.mask.astype(np.float32))
        # Mostly the tile holding the most pipe pixels (a pipe tends to cross a line once), else any.
        k = int(np.argmax(masks.sum(axis=(1, 2, 3)))) if rng.random() < 0.8 else int(rng.integers(len(starts)))
        inputs.append(tiles[k])
        targets.append(masks[k] > 0.5)
    return np.stack(inputs).astype(np.float16), np.stack(targets).astype(np.uint8)


def _scene_tiles_args(args: tuple[int, str]) -> tuple[NDArray[np.float16], NDArray[np.uint8]]:
    return scene_tiles(*args)


def cache_path(split: str) -> Path:
    """The .npz cache of a split."""
    return CACHE_DIR / f"migration_{split}_v{CACHE_VERSION}.npz"


def build_split(split: Literal["train", "val", "test"], workers: int = 1, limit: int | None = None) -> Path:
    """Generate (or reuse) the cached tiles of a split; returns the cache path."""
    path = cache_path(split) if limit is None else CACHE_DIR / f"migration_{split}_v{CACHE_VERSION}_n{limit}.npz"
    if path.exists():
        return path
    seeds = list(split_seeds(split))[:limit]
    start = time.perf_counter()
    jobs = [(s, split) for s in seeds]
    if workers > 1:
        with Pool(workers) as pool:
            parts = list(track(pool.imap(_scene_tiles_args, jobs, chunksize=8), f"{split} tiles", len(jobs), "scene"))
    else:
        parts = [_scene_tiles_args(j) for j in track(jobs, f"{split} tiles", unit="scene")]
    x = np.concatenate([p[0] for p in parts])
    y = np.concatenate([p[1] for p in parts])
    seconds = time.perf_counter() - start
    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, x=x, y=y, seeds=np.array(seeds), seconds=seconds)
    print(f"{split}: {len(seeds)} scenes → {len(x)} tiles {x.shape[1:]} in {seconds:.0f} s → {path}", flush=True)
    return path


def load_split(path: Path) -> tuple[NDArray[np.float16], NDArray[np.uint8]]:
    """Inputs and targets of a cached split."""
    with np.load(path) as data:
        return data["x"], data["y"]


def main() -> None:
    """CLI: build the cache of one or more splits."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("train", "val", "test"), action="append", required=True)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--limit", type=int, default=None, help="only the first N scenes (smoke runs)")
    args = parser.parse_args()
    for split in args.split:
        build_split(split, args.workers, args.limit)


if __name__ == "__main__":
    main()
