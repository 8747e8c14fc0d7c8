"""Tune the completion on the validation surveys: interpret once, then re-score the fit in seconds.

    python -m training.eval_completion_val cache --method classical    # interpret the 100 val surveys (~15 min)
    python -m training.eval_completion_val score --completion geometric [--per-survey]

The tracker, the blob linking and the fit run on a survey's interpreted slices; interpreting them is
what takes the time. `cache` interprets every line of each `val` survey (training.random_scenes, seeds
100000-100099) as the product does with the velocity estimated (the end-to-end table's setup:
training.eval_end_to_end.chain_config) and pickles the slices under training/cache/, keyed on the
interpretation's code version. `score` runs the completion on them and counts pipes found and extra
pipes per case (gprbot.simulated.evaluation, two-way matching), so a change to gprbot/reconstruct can
be measured on surveys never used for the test tables. The figures in the last notes on whole-section
blobs (97f816c) and the first link's spread (48cf6a3) came from this, then ad hoc.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from gprbot.config import load_config
from gprbot.gpr.preprocess import preprocess
from gprbot.infer.pipeline import complete_slices, interpret_line, survey_velocity
from gprbot.progress import track
from gprbot.reconstruct.extension import survey_footprint
from gprbot.reconstruct.register import resample_cloud
from gprbot.simulated.evaluation import compare_to_truth
from training.code_version import code_version
from training.e2e_surveys import simulated_lines, survey_region
from training.eval_end_to_end import chain_config
from training.random_scenes import CASES, scene_for_seed, split_seeds

CACHE = Path(__file__).resolve().parent / "cache"


def cache_dir(method: str) -> Path:
    """Where the interpreted slices of one method live, keyed on the interpretation's code version."""
    version = code_version(["gprbot.infer.pipeline", "training.e2e_surveys"])
    return CACHE / f"completion_val_{method}_{version}"


def interpret_survey(seed: int, method: str) -> dict[str, Any]:
    """The interpreted slices and footprint of one val survey, velocity estimated."""
    base = load_config()
    _, _, bscans, gpr = simulated_lines(seed, base.gpr)
    cfg = chain_config(base, gpr, method, "geometric")
    processed = {line: preprocess(b, cfg.gpr) for line, b in bscans.items()}
    velocity = survey_velocity(processed, cfg)
    slices = [interpret_line(line, b, cfg, velocity.v, velocity.hints).slice for line, b in processed.items()]
    footprint = survey_footprint({line: b.positions for line, b in processed.items()})
    return {"seed": seed, "case": CASES[seed % len(CASES)], "slices": slices, "footprint": footprint}


def build_cache(method: str, limit: int | None = None) -> Path:
    """Interpret the val surveys not yet cached; returns the cache folder."""
    folder = cache_dir(method)
    folder.mkdir(parents=True, exist_ok=True)
    for seed in track(list(split_seeds("val"))[:limit], f"val surveys ({method})", unit="survey"):
        path = folder / f"{seed}.pkl"
        if not path.exists():
            tmp = path.with_suffix(".tmp")
            tmp.write_bytes(pickle.dumps(interpret_survey(seed, method)))
            tmp.replace(path)
    return folder


def score(method: str, completion: str, per_survey: bool = False) -> dict[str, list[int]]:
    """Pipes found, true pipes and extra pipes per case, over the cached surveys."""
    folder = cache_dir(method)
    files = sorted(folder.glob("*.pkl"))
    if not files:
        raise SystemExit(f"no cached surveys in {folder}: run `python -m training.eval_completion_val cache "
                         f"--method {method}` first")
    base = load_config()
    cfg = dataclasses.replace(base, reconstruction=dataclasses.replace(base.reconstruction, completion=completion))
    totals: dict[str, list[int]] = collections.defaultdict(lambda: [0, 0, 0])
    for path in files:
        survey = pickle.loads(path.read_bytes())
        scene, spec = scene_for_seed(survey["seed"])
        slices = survey["slices"]
        points = np.concatenate([s.points for s in slices]) if slices else np.zeros((0, 3))
        sparse = (resample_cloud(points, cfg.reconstruction.sparse_points, np.random.default_rng(1))
                  if len(points) else points)
        recon, _ = complete_slices(slices, sparse, cfg, np.random.default_rng(2), survey["footprint"])
        matches, extras = compare_to_truth(recon.pipes, scene, survey_region(spec))
        found = sum(m.found is not None for m in matches)
        row = totals[survey["case"]]
        row[0], row[1], row[2] = row[0] + found, row[1] + len(matches), row[2] + len(extras)
        if per_survey:
            print(f"{survey['seed']} {survey['case']}: {found}/{len(matches)} found, {len(extras)} extra", flush=True)
    return dict(totals)


def main(argv: list[str] | None = None) -> int:
    """CLI."""
    parser = argparse.ArgumentParser(prog="python -m training.eval_completion_val", description=__doc__.splitlines()[0])
    parser.add_argument("action", choices=("cache", "score"))
    parser.add_argument("--method", default="classical", choices=("classical", "migrationnet", "chain"))
    parser.add_argument("--completion", default="geometric", help="geometric, extended or refined")
    parser.add_argument("--limit", type=int, default=None, help="cache only the first N surveys")
    parser.add_argument("--per-survey", action="store_true")
    args = parser.parse_args(argv)
    if args.action == "cache":
        print(build_cache(args.method, args.limit))
        return 0
    totals = score(args.method, args.completion, args.per_survey)
    found, true, extra = (sum(t[i] for t in totals.values()) for i in range(3))
    print(" ".join(f"{case} {t[0]}/{t[1]}+{t[2]}" for case, t in sorted(totals.items())))
    print(f"all: {found}/{true} pipes found, {extra} extra; recall {found / max(true, 1):.3f}, "
          f"precision {found / max(found + extra, 1):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
