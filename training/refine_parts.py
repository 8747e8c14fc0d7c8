"""Which part of the FitRefiner changes the refined completion: its acceptance of candidate points, or their offsets?

    python -m training.refine_parts --limit 60                      # validation surveys, classical path
    python -m training.refine_parts --model models/fit_refiner_s1.onnx --method migrationnet

Each validation survey (training.e2e_surveys, the split the pipe thresholds are chosen on; the test surveys are
not read) is interpreted as the product does (velocity estimated) and completed four ways from the same slices
and random stream: the rule (`extended`), the network (`refined`), the network's acceptance with the points left
where the rule put them, and every candidate accepted but moved by the network. Prints median and mean CD2×10³,
pipes and the per-case medians of each; first, how many candidate points of training.refine_data's validation
samples the network rejects, and how many of them lie outside every true pipe (the acceptance's whole job).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.config import Config, load_config
from gprbot.errors import GprbotError
from gprbot.infer.pipeline import interpret_line
from gprbot.infer.refine import ACCEPT, FIT_POINTS, FitRefinerModel, onehot, refined_reconstruction
from gprbot.reconstruct.register import resample_cloud
from training.e2e_surveys import simulated_survey
from training.eval_end_to_end import _RNG_TAG, chain_config, prepare_survey, score_row
from training.pointcloud_data import load_split
from training.refine_data import build_split

VARIANTS = ("rule", "network", "acceptance only", "offsets only")


class Swapped:
    """A FitRefiner whose acceptance or offsets are replaced by the rule's (accept all; leave in place)."""

    def __init__(self, model: FitRefinerModel, keep: str) -> None:
        self.model, self.keep, self.pipe_threshold = model, keep, model.pipe_threshold

    def run(self, sparse: NDArray[np.float32], fit: NDArray[np.float32], fit_pipes: NDArray[np.float32],
            query: NDArray[np.float32], query_pipes: NDArray[np.float32],
            beyond: NDArray[np.float32]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The network's outputs with one of them the rule's."""
        probability, moved = self.model.run(sparse, fit, fit_pipes, query, query_pipes, beyond)
        if self.keep == "acceptance only":
            return probability, np.asarray(query, dtype=np.float64)
        return np.ones_like(probability), moved


def acceptance_line(model: FitRefinerModel) -> str:
    """How many candidates of the validation samples the model rejects (probability under ACCEPT), against how many
    lie outside every true pipe, in all and past the fitted part."""
    data = build_split("val")
    rejected = outside = rejected_past = outside_past = total = 0
    for i in range(len(data["seed"])):
        fit = slice(0, FIT_POINTS)  # the runtime's count of the sample's fitted-rod points
        probability, _ = model.run(data["sparse"][i], data["fit"][i][fit], onehot(data["fit_pipe"][i][fit]),
                                   data["query"][i], onehot(data["query_pipe"][i]), data["beyond"][i])
        out, past, no = data["inside"][i] < 0.5, data["beyond"][i] > 0.0, probability < ACCEPT
        rejected, outside, total = rejected + int(no.sum()), outside + int(out.sum()), total + len(no)
        rejected_past += int((no & past & out).sum())
        outside_past += int((past & out).sum())
    return (f"validation samples ({len(data['seed'])}): {rejected} of {total} candidates rejected, {outside} lie "
            f"outside every true pipe; past the fitted part {rejected_past} of the {outside_past} outside rejected")


def survey_rows(index: int, data: Any, method: str, model: FitRefinerModel, base: Config) -> dict[str, dict[str, Any]]:
    """The four completions' scores on one validation survey ({} when the survey is refused)."""
    survey = simulated_survey(index, data, base.gpr)
    cfg = chain_config(base, survey.gpr, method, "extended")
    try:
        prepared = prepare_survey(survey, cfg)
        slices = [interpret_line(line, b, cfg, prepared.velocity, prepared.hints).slice
                  for line, b in prepared.processed.items()]
    except GprbotError:
        return {}
    footprint = prepared.footprint
    points = np.concatenate([s.points for s in slices])
    if not len(points):
        return {}
    sparse = resample_cloud(points, cfg.reconstruction.sparse_points, np.random.default_rng([survey.seed, _RNG_TAG, 1]))
    models = {"rule": None, "network": model, "acceptance only": Swapped(model, "acceptance only"),
              "offsets only": Swapped(model, "offsets only")}
    rows = {}
    for name, m in models.items():
        try:
            recon = refined_reconstruction(slices, sparse, footprint, cfg.reconstruction, m,  # type: ignore[arg-type]
                                           np.random.default_rng([survey.seed, _RNG_TAG, 2]))
        except GprbotError:
            continue
        rows[name] = score_row(survey, recon, recon.dense if len(recon.dense) else sparse) | {"case": survey.case}
    return rows


def main() -> None:
    """Score the four completions on the first --limit validation surveys and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--limit", type=int, default=60)
    parser.add_argument("--method", default="classical", choices=("classical", "chain", "migrationnet"))
    parser.add_argument("--model", type=Path, default=Path("models/fit_refiner.onnx"))
    args = parser.parse_args()
    model, base = FitRefinerModel(args.model, threads=2), load_config()
    print(acceptance_line(model), flush=True)
    data = load_split("val")
    rows: dict[str, list[dict[str, Any]]] = {v: [] for v in VARIANTS}
    for i in range(min(args.limit, len(data["seed"]))):
        for name, row in survey_rows(i, data, args.method, model, base).items():
            rows[name].append(row)
        print(f"survey {i + 1}/{args.limit}", flush=True)
    cases = sorted({r["case"] for r in rows["rule"]})
    print(f"\n{args.model}, {args.method} path, {len(rows['rule'])} validation surveys (CD2×10³)")
    print("| completion | median | mean | pipes found | extra | " + " | ".join(cases) + " |")
    print("|---" * (5 + len(cases)) + "|")
    for name, mine in rows.items():
        cd2 = [r["cd2"] for r in mine if r["cd2"] is not None]
        per_case = [np.median([r["cd2"] for r in mine if r["case"] == c and r["cd2"] is not None]) for c in cases]
        found, true, extra = (sum(r[k] for r in mine) for k in ("found", "true", "extra"))
        print(f"| {name} | {1e3 * np.median(cd2):.3f} | {1e3 * np.mean(cd2):.2f} | {found}/{true} | {extra} | "
              + " | ".join(f"{1e3 * v:.2f}" for v in per_case) + " |")


if __name__ == "__main__":
    main()
