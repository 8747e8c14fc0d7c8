"""The FitRefiner's pipe threshold, chosen on the validation surveys: below it a fitted pipe is dropped as false.

    python -m training.refine_pipe_threshold models/fit_refiner.onnx models/fit_refiner_s1.onnx \\
        models/fit_refiner_s2.onnx --limit 80

A fitted pipe's score is the network's mean probability over the candidate points inside its fitted part
(`gprbot.infer.refine.pipe_scores`). The rule continues every fitted pipe; the network's points say more:
on a false pipe (clutter seen from the neighbouring lines, a rebar's echo, a broken track's stray piece) they
score lower, but the scores of false and true pipes overlap above 0.5, so "most of it accepted" dropped no
false pipe at all. Each model gets the threshold that, on the first `--limit` surveys of the *validation*
split (interpreted as the product does: velocity estimated, the classical path and MigrationNet each),
drops the most false pipes net of LOST_TRUE_COST per other pipe it would drop (missing a utility costs more
than a false alarm); ties go to the lowest. A false pipe is an extra of the two-way matching that lies along
no real pipe: a stray piece of a real pipe the tracker broke off is an extra too, but dropping it loses that
part of the pipe (`gprbot.simulated.evaluation.lies_on_a_pipe`). The threshold and what it did there go
into the model's card, which the runtime reads. The test surveys (`training.eval_end_to_end`) are not
looked at.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from gprbot.config import Config, load_config
from gprbot.errors import GprbotError
from gprbot.infer.gprnet import normalisation
from gprbot.infer.pipeline import interpret_line
from gprbot.infer.refine import FIT_POINTS, QUERY_POINTS, SPARSE_POINTS, FitRefinerModel, onehot, pipe_scores
from gprbot.reconstruct.completion import fit_pipes
from gprbot.reconstruct.extension import RodCandidates, rod_candidates
from gprbot.reconstruct.register import resample_cloud
from gprbot.simulated.evaluation import compare_to_truth, lies_on_a_pipe
from training.code_version import code_version
from training.e2e_surveys import simulated_survey
from training.eval_end_to_end import chain_config, prepare_survey
from training.pointcloud_data import load_split

ROOT = Path(__file__).resolve().parents[1]
CACHE_DIR = ROOT / "training" / "cache"
INTERPRETERS = ("classical", "migrationnet")  # the two the FitRefiner is trained on and shipped with
LOST_TRUE_COST = 2.0
GRID = np.round(np.arange(0.5, 0.995, 0.005), 3)
_RNG_TAG = 0x505448


def survey_rows(index: int, data: Any, base: Config, models: dict[str, FitRefinerModel]) -> list[dict[str, Any]]:
    """Every fitted pipe of one validation survey, per interpreter: each model's score and whether it is false."""
    survey = simulated_survey(index, data, base.gpr)
    # Preprocessing and the survey's velocity do not depend on the interpreter: once per survey, as
    # training.eval_end_to_end does.
    try:
        prepared = prepare_survey(survey, chain_config(base, survey.gpr, INTERPRETERS[0], "refined"))
    except GprbotError:
        return []  # a refused survey has no pipe to keep or drop
    processed, velocity, hints, footprint = (prepared.processed, prepared.velocity, prepared.hints,
                                             prepared.footprint)
    rows = []
    for method in INTERPRETERS:
        cfg = chain_config(base, survey.gpr, method, "refined")
        try:
            slices = [interpret_line(line, b, cfg, velocity, hints).slice for line, b in processed.items()]
        except GprbotError:
            continue
        points = np.concatenate([s.points for s in slices])
        pipes = fit_pipes(slices, cfg.reconstruction)
        if not pipes or not len(points):
            continue
        rng = np.random.default_rng([survey.seed, _RNG_TAG])
        sparse = resample_cloud(points, SPARSE_POINTS, rng)
        candidates = rod_candidates(pipes, footprint, FIT_POINTS, QUERY_POINTS, rng, slices)
        if candidates is None:
            continue
        _, extras = compare_to_truth(pipes, survey.truth, survey.region)
        scores = {name: scored(model, sparse, candidates, len(pipes)) for name, model in models.items()}
        rows += [{"survey": survey.name, "case": survey.case, "interpretation": method, "pipe": k,
                  "false": k in extras and not lies_on_a_pipe(p, survey.truth, survey.region),
                  "extra": k in extras, "n_slices": p.n_slices, **{f"score:{n}": s[k] for n, s in scores.items()}}
                 for k, p in enumerate(pipes)]
    return rows


def scored(model: FitRefinerModel, sparse: np.ndarray, candidates: RodCandidates, n_pipes: int) -> list[float]:
    """One model's score of each fitted pipe (the runtime's normalisation and inputs)."""
    centre, scale = normalisation(sparse)

    def unit(x: np.ndarray) -> np.ndarray:
        return ((x - centre) / scale).astype(np.float32)

    probability, _ = model.run(unit(sparse), unit(candidates.fit), onehot(candidates.fit_pipe),
                               unit(candidates.query), onehot(candidates.query_pipe),
                               (candidates.beyond_m / scale).astype(np.float32))
    return pipe_scores(probability, candidates.query_pipe, candidates.beyond_m, n_pipes)


def choose(false_scores: np.ndarray, true_scores: np.ndarray) -> tuple[float, int, int]:
    """(threshold, false pipes dropped, true pipes dropped) of the best net gain on GRID; ties to the lowest."""
    gains = [(float(np.sum(false_scores < t)) - LOST_TRUE_COST * float(np.sum(true_scores < t)), -t) for t in GRID]
    t = -max(gains)[1]
    return t, int(np.sum(false_scores < t)), int(np.sum(true_scores < t))


def main() -> None:
    """Score the validation surveys' fitted pipes with each model, choose its threshold, write it to its card."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", type=Path)
    parser.add_argument("--limit", type=int, default=80, help="the first N surveys of the validation split")
    parser.add_argument("--dry-run", action="store_true", help="print the choice, leave the cards alone")
    args = parser.parse_args()
    models = {str(m): FitRefinerModel(m, threads=1) for m in args.models}
    data = load_split("val")
    base = load_config()
    count = min(args.limit, len(data["seed"]))
    version = code_version(["training.refine_pipe_threshold"], [Path(m) for m in args.models])
    cache = CACHE_DIR / f"refine_pipe_scores_{version}_{count}.json"
    if cache.exists():
        rows = json.loads(cache.read_text())
    else:
        rows = []
        for i in range(count):
            rows += survey_rows(i, data, base, models)
            print(f"survey {i + 1}/{count}: {len(rows)} fitted pipes so far", flush=True)
        CACHE_DIR.mkdir(parents=True, exist_ok=True)
        cache.write_text(json.dumps(rows))
    for name in models:
        false = np.array([r[f"score:{name}"] for r in rows if r["false"]])
        true = np.array([r[f"score:{name}"] for r in rows if not r["false"]])
        t, dropped_false, dropped_true = choose(false, true)
        print(f"{name}: {len(rows)} fitted pipes on {count} validation surveys ({', '.join(INTERPRETERS)}), "
              f"{len(false)} false; threshold {t:.3f} drops {dropped_false} false and {dropped_true} true "
              f"(at 0.5: {int(np.sum(false < 0.5))} and {int(np.sum(true < 0.5))})")
        if args.dry_run:
            continue
        card_path = Path(name).with_suffix(".json")
        card = json.loads(card_path.read_text())
        card["pipe_threshold"] = t
        card["pipe_threshold_selection"] = {
            "command": f"python -m training.refine_pipe_threshold {' '.join(str(m) for m in args.models)} "
                       f"--limit {args.limit}",
            "split": "val", "surveys": count, "interpreters": list(INTERPRETERS), "fitted_pipes": len(rows),
            "false_pipes": len(false), "false_dropped": dropped_false, "true_dropped": dropped_true,
            "lost_true_cost": LOST_TRUE_COST,
        }
        card_path.write_text(json.dumps(card, indent=2, default=float) + "\n")
        print(f"wrote {card_path}")


if __name__ == "__main__":
    main()
