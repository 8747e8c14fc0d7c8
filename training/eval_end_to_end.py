"""The whole chain, nothing given: raw B-scans → interpretation → registration → completion → pipes and cloud.

    python -m training.eval_end_to_end --limit 60          # simulated: models/eval_end_to_end.{md,json}
    python -m training.eval_end_to_end --source fdtd       # FDTD test half: models/eval_end_to_end_fdtd.{md,json}

training.evaluate scores the completion models on degraded *truth* masks and training.eval_migration
scores interpretation alone with the *true* velocity. Here every survey (training.e2e_surveys: held-out
simulated test scenes, or the FDTD test half laid on parallel lines) goes through the product's own
stages: preprocessing, the velocity estimated from the hyperbolas (eps_r unknown), each line interpreted
by the classical path, the interpretation chain (gprbot.gpr.chain, with the survey's crossing hints) or
MigrationNet, the slices registered at the recorded positions and completed by
the runtime's completion dispatch (gprbot.infer.pipeline.complete_slices) for every name in COMPLETIONS.
Reported per chain: the dense cloud's CD2×10³ / CD1×10² / F@1% in the survey's unit cube (all chains
share one scale), and the pipes against the truth (gprbot.simulated.evaluation, two-way matching). Every
survey is counted: a chain that refuses one has found nothing there.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gprbot.config import Config, GprConfig, load_config
from gprbot.errors import GprbotError
from gprbot.gpr.bscan import BScan
from gprbot.gpr.preprocess import preprocess
from gprbot.gpr.velocity import CrossingHint
from gprbot.infer.pipeline import complete_slices, interpret_line, survey_velocity
from gprbot.progress import track
from gprbot.reconstruct.completion import Reconstruction
from gprbot.reconstruct.extension import Footprint, survey_footprint
from gprbot.reconstruct.register import resample_cloud
from gprbot.simulated.evaluation import compare_to_truth
from training.chamfer import cloud_metrics
from training.code_version import code_version
from training.e2e_surveys import Survey, survey_makers
from training.random_scenes import CASES

ROOT = Path(__file__).resolve().parents[1]
INTERPRETERS = ("classical", "chain", "migrationnet")
# names of reconstruction.completion; a new one is scored by adding it here
# refined_sK: the refined completion with the FitRefiner of training seed K (models/fit_refiner_sK.onnx), the spread
COMPLETIONS = ("geometric", "extended", "refined", "refined_s1", "refined_s2", "gprnet")
_RNG_TAG = 0xE2E
NOTHING = np.zeros((1, 3), dtype=np.float32)  # "nothing found": one point at the centre of the unit cube


def chain_config(base: Config, gpr: GprConfig, method: str, completion: str) -> Config:
    """The product config for one chain on one survey, given its antenna settings (eps_r left unknown)."""
    reconstruction = dataclasses.replace(base.reconstruction, completion=completion)  # type: ignore[arg-type]
    if completion.startswith("refined_s"):
        reconstruction = dataclasses.replace(reconstruction, completion="refined",
                                             refiner_model=f"models/fit_refiner_{completion.split('_')[1]}.onnx")
    return dataclasses.replace(
        base, gpr=gpr, interpretation=dataclasses.replace(base.interpretation, method=method),
        reconstruction=reconstruction,
    )


@dataclasses.dataclass(frozen=True)
class PreparedSurvey:
    """What every interpreter of a survey shares: its lines preprocessed, the survey's velocity and crossing hints,
    and the footprint its lines cover."""

    processed: dict[int, BScan]
    velocity: float
    hints: tuple[CrossingHint, ...]
    footprint: Footprint


def prepare_survey(survey: Survey, cfg: Config) -> PreparedSurvey:
    """Preprocess every line and estimate the survey's velocity once (neither depends on the interpreter); raises
    GprbotError where no velocity is found, as the product refuses the survey."""
    processed = {line: preprocess(b, cfg.gpr) for line, b in survey.bscans.items()}
    found = survey_velocity(processed, cfg)
    return PreparedSurvey(processed, found.v, tuple(found.hints),
                          survey_footprint({line: b.positions for line, b in processed.items()}))


def score_row(survey: Survey, recon: Reconstruction, cloud: NDArray[np.float64] | None) -> dict[str, Any]:
    """Cloud metrics (None without a truth cloud) and found / missed / extra pipes with the found ones' errors.

    `cloud` is what the chain answers in metres; None when it answered nothing (refused, or nothing registered).
    """
    matches, extras = compare_to_truth(recon.pipes, survey.truth, survey.region)
    found = [m for m in matches if m.found is not None]
    # missed although a found axis lies along them: pieces the coverage gate does not count as the pipe
    partial = sum(1 for m in matches if m.found is None and m.partial is not None)
    row: dict[str, Any] = {"true": len(matches), "found": len(found), "extra": len(extras), "partial": partial,
                           "horizontal_m": [m.horizontal_err_m for m in found],
                           "depth_m": [m.depth_err_m for m in found],
                           "diameter_rel": [m.diameter_err_rel for m in found], "cd2": None, "cd1": None,
                           "fscore": None}
    if survey.dense is not None:
        unit = NOTHING if cloud is None else np.asarray((cloud - survey.centre) / survey.scale, dtype=np.float32)
        m = cloud_metrics(unit, survey.dense)
        row |= {"cd2": m.cd2, "cd1": m.cd1, "fscore": m.fscore}
    return row


def evaluate_survey(survey: Survey, base: Config) -> list[dict[str, Any]]:
    """Every chain on one survey; one row per (interpreter, completion), refusals included."""
    empty = Reconstruction(pipes=(), dense=np.zeros((0, 3)), labels=np.zeros(0, dtype=np.intp))
    head = {"survey": survey.name, "seed": survey.seed, "case": survey.case}

    def refused(method: str, completion: str, exc: GprbotError) -> dict[str, Any]:
        return {**head, "interpretation": method, "completion": completion, "refused": str(exc),
                "velocity_err_rel": None, "interpret_s": None, **score_row(survey, empty, None)}

    try:
        prepared = prepare_survey(survey, chain_config(base, survey.gpr, "classical", COMPLETIONS[0]))
    except GprbotError as exc:  # no velocity: every chain refuses the survey
        return [refused(m, c, exc) for m in INTERPRETERS for c in COMPLETIONS]
    processed, velocity, hints, footprint = (prepared.processed, prepared.velocity, prepared.hints,
                                             prepared.footprint)
    rows = []
    for method in INTERPRETERS:
        cfg = chain_config(base, survey.gpr, method, COMPLETIONS[0])
        start = time.perf_counter()
        try:
            slices = [interpret_line(line, b, cfg, velocity, hints).slice for line, b in processed.items()]
        except GprbotError as exc:
            rows += [refused(method, c, exc) for c in COMPLETIONS]
            continue
        interpret_s = time.perf_counter() - start
        points = np.concatenate([s.points for s in slices])
        rng = np.random.default_rng([survey.seed, _RNG_TAG, 1])
        sparse = resample_cloud(points, cfg.reconstruction.sparse_points, rng) if len(points) else points
        for completion in COMPLETIONS:
            try:  # each completion gets the same random stream, so they differ by the method alone
                recon, _ = complete_slices(slices, sparse, chain_config(base, survey.gpr, method, completion),
                                           np.random.default_rng([survey.seed, _RNG_TAG, 2]), footprint)
            except GprbotError as exc:
                rows.append(refused(method, completion, exc))
                continue
            # no pipe found: the sparse cloud is the answer; nothing registered: nothing found
            cloud = recon.dense if len(recon.dense) else (sparse if len(sparse) else None)
            rows.append({**head, "interpretation": method, "completion": completion, "refused": None,
                         "velocity_err_rel": float(velocity / survey.true_velocity - 1.0),
                         "interpret_s": interpret_s, **score_row(survey, recon, cloud)})
    return rows


def _median(values: Sequence[float], scale: float = 1.0) -> float:
    return scale * float(np.median(values)) if len(values) else float("nan")


def summarise(rows: Sequence[dict[str, Any]]) -> dict[str, float]:
    """Cloud-metric means and medians (surveys with a truth cloud), pipe totals and median errors."""
    pooled = {k: [v for r in rows for v in r[k]] for k in ("horizontal_m", "depth_m", "diameter_rel")}
    true, found, extra, partial = (int(sum(r[k] for r in rows)) for k in ("true", "found", "extra", "partial"))
    clouds = [r for r in rows if r["cd2"] is not None]
    cd2 = [r["cd2"] for r in clouds]
    nan = float("nan")
    return {
        "scenes": len(rows), "refused": sum(1 for r in rows if r["refused"]), "clouds": len(clouds),
        "cd2_e3": 1e3 * float(np.mean(cd2)) if cd2 else nan,
        # the mean is ruled by a few scenes whose unit cube is tiny; the median is not
        "median_cd2_e3": _median(cd2, 1e3),
        "cd1_e2": 1e2 * float(np.mean([r["cd1"] for r in clouds])) if clouds else nan,
        "fscore": float(np.mean([r["fscore"] for r in clouds])) if clouds else nan,
        "true_pipes": true, "found_pipes": found, "extra_pipes": extra, "partial_pipes": partial,
        "pipe_recall": found / true if true else nan,
        "pipe_precision": found / (found + extra) if found + extra else nan,
        "median_horizontal_cm": _median(pooled["horizontal_m"], 100.0),
        "median_depth_cm": _median(pooled["depth_m"], 100.0),
        "median_abs_diameter_pct": _median(np.abs(pooled["diameter_rel"]).tolist(), 100.0),
    }


def evaluate(surveys: Sequence[Callable[[], Survey]], source: str) -> dict[str, Any]:
    """Every chain on every survey (built lazily, one at a time), summarised overall and per case."""
    base = load_config()
    version = code_version(["training.eval_end_to_end"])  # of the code that runs (files may change during a run)
    rows: list[dict[str, Any]] = []
    start = time.perf_counter()
    for i, make in enumerate(track(surveys, "surveys", unit="survey")):
        rows += evaluate_survey(make(), base)
        print(f"{i + 1}/{len(surveys)} surveys, {time.perf_counter() - start:.0f} s, load {os.getloadavg()[0]:.1f}",
              flush=True)
    cases = [c for c in dict.fromkeys([*CASES, *(r["case"] for r in rows)]) if any(r["case"] == c for r in rows)]
    chains: dict[str, dict[str, dict[str, float]]] = {}
    for method in INTERPRETERS:
        for completion in COMPLETIONS:
            mine = [r for r in rows if r["interpretation"] == method and r["completion"] == completion]
            chains[f"{method} + {completion}"] = {
                case: summarise([r for r in mine if case == "all" or r["case"] == case]) for case in ("all", *cases)}
    first = [r for r in rows if r["interpretation"] == INTERPRETERS[0] and r["completion"] == COMPLETIONS[0]]
    velocity = [abs(r["velocity_err_rel"]) for r in first if r["velocity_err_rel"] is not None]
    timed = {m: [r["interpret_s"] for r in rows if r["interpretation"] == m and r["interpret_s"] is not None]
             for m in INTERPRETERS}
    refusals = sorted({f"{r['survey']} ({r['interpretation']}): {r['refused']}" for r in rows if r["refused"]})
    return {"source": source, "scenes": len(surveys), "cases": {c: sum(1 for r in first if r["case"] == c)
                                                                 for c in cases},
            "refusals": refusals, "chains": chains, "rows": rows,
            "median_abs_velocity_err_pct": _median(velocity, 100.0),
            "velocity_not_estimated": len(first) - len(velocity),
            "median_interpret_s_per_scene": {m: _median(t) for m, t in timed.items()},
            "code_version": version, "seconds": time.perf_counter() - start,
            "load_average": os.getloadavg()[0]}


PIPE_RULE = ("Pipes (gprbot.simulated.evaluation, two-way): a truth pipe is found when a found axis lies along it "
             "(mean horizontal distance ≤ 15 cm) and follows it within 5 cm over ≥ 50 % of its surveyed length; "
             "recall = found / true, precision = found / (found + extra). Partly: missed pipes that a found axis lies "
             "along but follows over too little of their length (a miss; the piece is an extra).")
SOURCES = {
    "sim": ("End to end from simulated B-scans, velocity estimated",
            "Feeds it: every kept line of each held-out test scene (training.random_scenes split 'test', in seed "
            "order) simulated by gprbot's forward model — pose noise, clutter, rebar and missing lines as drawn. "
            "Cloud metrics in the test sample's unit cube (training.pointcloud_data's normalisation of its "
            "degraded-truth-mask cloud)."),
    "fdtd": ("End to end from FDTD B-scans (gprMax 2D), velocity estimated",
             "Feeds it: the FDTD test half (validation/fdtd; the dev half is for tuning), each scene's B-scan laid "
             "on every line of a survey whose line count, spacing, pose noise and receiver noise are drawn as the "
             "random scenes draw them (training.e2e_surveys); truth: the scene's pipes extruded across the lines. "
             "It measures the chains on physics independent of gprbot's simulator, but only for straight pipes "
             "crossing the lines at 90° — no bends, tees, oblique crossings or missing lines. Cloud metrics in the "
             "unit cube of the truth cloud's bounding box; a scene without pipes has no cloud score, only extras."),
}


def _cell(value: float, fmt: str) -> str:
    return "–" if value != value else format(value, fmt)


def _same_pipes(result: dict[str, Any], chain: str) -> str | None:
    """The chain with the same interpreter and the first completion, when its pipe columns are identical."""
    method, completion = chain.split(" + ")
    other = f"{method} + {COMPLETIONS[0]}"
    keys = ("found_pipes", "extra_pipes", "true_pipes", "median_horizontal_cm")
    mine, theirs = result["chains"][chain]["all"], result["chains"][other]["all"]
    if completion != COMPLETIONS[0] and all(mine[k] == theirs[k] or mine[k] != mine[k] for k in keys):
        return other
    return None


HARD_CASES = ("bend", "tee", "missing")  # where the issue asks the learned completion for ≤ 0.7× the fit


def target_lines(result: dict[str, Any]) -> list[str]:
    """The learned completion's targets against the geometric fit, per interpreter; and against the rule."""
    chains = result["chains"]
    lines = ["## Targets (refined vs geometric, median CD2; ≤ 0.7× on bend, tee and missing, ≤ 1.0× overall, "
             "recall and precision no worse)", ""]
    for method in INTERPRETERS:
        fit, ours, rule = (chains.get(f"{method} + {c}") for c in ("geometric", "refined", "extended"))
        if fit is None or ours is None:
            continue
        cells = []
        for case in (*HARD_CASES, "all"):
            if case in fit and case in ours:
                ratio = ours[case]["median_cd2_e3"] / fit[case]["median_cd2_e3"]
                bar = 1.0 if case == "all" else 0.7
                cells.append(f"{case} {ratio:.2f}× ({'met' if ratio <= bar else 'NOT met'})")
        a, f = ours["all"], fit["all"]
        recall = "met" if a["pipe_recall"] >= f["pipe_recall"] else "NOT met"
        precision = "met" if a["pipe_precision"] >= f["pipe_precision"] else "NOT met"
        lines.append(f"* {method}: {', '.join(cells)}; recall {a['pipe_recall']:.3f} vs {f['pipe_recall']:.3f} "
                     f"({recall}), precision {a['pipe_precision']:.3f} vs {f['pipe_precision']:.3f} ({precision})")
        if rule is not None:
            by_case = ", ".join(f"{c} {ours[c]['median_cd2_e3'] / rule[c]['median_cd2_e3']:.2f}×"
                                for c in (*HARD_CASES, "all") if c in ours and c in rule)
            r = rule["all"]
            lines.append(f"  - the network's own share (refined / the fit continued by rule, median CD2): {by_case}; "
                         f"mean CD2 {a['cd2_e3']:.2f} vs {r['cd2_e3']:.2f}, recall {a['pipe_recall']:.3f} vs "
                         f"{r['pipe_recall']:.3f}, precision {a['pipe_precision']:.3f} vs {r['pipe_precision']:.3f} "
                         "(the network drops the fitted pipes it scores under its card's pipe threshold)")
    return [*lines, ""] if len(lines) > 2 else []


def markdown(result: dict[str, Any], command: str) -> str:
    """The chains as markdown tables: overall, then median CD2 and pipe recall per case."""
    title, feeds = SOURCES[result["source"]]
    if result.get("half") == "dev":  # the tuning half: say so (the test half is the report)
        feeds = feeds.replace("the FDTD test half (validation/fdtd; the dev half is for tuning)",
                              "the FDTD dev half (validation/fdtd; the half tuned on: report the test half, "
                              "eval_end_to_end_fdtd.md)")
    if result.get("half") == "train":  # the training batch: a third, untuned draw of the random scenes
        feeds = feeds.replace("the FDTD test half (validation/fdtd; the dev half is for tuning)",
                              "the FDTD training batch (validation/fdtd, training_scenes: 40 random scenes in "
                              "neither half, no shipped model trained on them)")
    cases = result["cases"]
    refused = result["refusals"]
    lines = [
        f"# {title}: {result['scenes']} surveys", "",
        f"{feeds} Scenes per case: {', '.join(f'{c} {n}' for c, n in cases.items())}.", "",
        "Nothing is given: eps_r unknown, the velocity is estimated from the hyperbolas of all lines (median "
        f"|error| {_cell(result['median_abs_velocity_err_pct'], '.1f')} %, not estimated on "
        f"{result['velocity_not_estimated']} surveys). Every survey is scored: a chain that refuses one "
        f"({len(refused)} refusals, listed below) found nothing there — its truth pipes are misses and its cloud "
        "scores as nothing found, one point at the centre of the unit cube; a chain that registers points but fits "
        "no pipe answers its sparse cloud. Cloud: CD2×10³, CD1×10², F@1%.", "", PIPE_RULE,
    ]
    repeats = [(c, o) for c in result["chains"] if (o := _same_pipes(result, c))]
    if repeats:
        lines.append(" ".join(f"`{c}` has `{o}`'s pipe columns (its pipes.json comes from the geometric fit)."
                              for c, o in repeats))
    lines += ["", "| chain | surveys | refused | CD2×10³ | median CD2×10³ | CD1×10² | F@1% | pipes found | "
              "partly | recall | precision | horiz cm | depth cm | abs diam % |", "|---" * 14 + "|"]
    for chain, per in result["chains"].items():
        a = per["all"]
        lines.append(f"| {chain} | {a['scenes']} | {a['refused']} | {_cell(a['cd2_e3'], '.2f')} | "
                     f"{_cell(a['median_cd2_e3'], '.2f')} | {_cell(a['cd1_e2'], '.2f')} | "
                     f"{_cell(a['fscore'], '.3f')} | "
                     f"{a['found_pipes']}/{a['true_pipes']} (+{a['extra_pipes']} extra) | {a['partial_pipes']} | "
                     f"{_cell(a['pipe_recall'], '.3f')} | {_cell(a['pipe_precision'], '.3f')} | "
                     f"{_cell(a['median_horizontal_cm'], '.1f')} | {_cell(a['median_depth_cm'], '.1f')} | "
                     f"{_cell(a['median_abs_diameter_pct'], '.0f')} |")
    lines += ["", "Per case (median CD2×10³ / pipe recall; surveys per case in the header):", "",
              "| chain | " + " | ".join(f"{c} ({n})" for c, n in cases.items()) + " |", "|---" * (len(cases) + 1) + "|"]
    for chain, per in result["chains"].items():
        cells = [f"{_cell(per[c]['median_cd2_e3'], '.2f')} / {_cell(per[c]['pipe_recall'], '.2f')}" for c in cases]
        lines.append(f"| {chain} | " + " | ".join(cells) + " |")
    timing = ", ".join(f"{m} {_cell(s, '.2f')} s" for m, s in result["median_interpret_s_per_scene"].items())
    lines += ["", f"Interpretation per survey (median, all lines): {timing}. Whole run {result['seconds'] / 60:.0f} "
              f"min at load average {result['load_average']:.1f} (2-core CPU shared with other jobs); code version "
              f"{result['code_version']} (training.code_version).", ""]
    lines += target_lines(result)
    if refused:
        lines += ["Refusals:", "", *(f"- {r}" for r in refused), ""]
    lines += ["## Reproduce", "", "```", command, "```", ""]
    return "\n".join(lines)


def main() -> None:
    """CLI: run the chains on one source and write the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", choices=tuple(SOURCES), default="sim")
    parser.add_argument("--limit", type=int, default=60,
                        help="sim: the first N test scenes in seed order (150 in the split; 60 take ~15 min here)")
    parser.add_argument("--half", choices=("test", "dev", "train", "holdout"), default="test",
                        help="fdtd: which half (report: test; train: the training batch; holdout: only as "
                             "validation/README.md's holdout rule says)")
    parser.add_argument("--out", type=Path, default=None, help="default models/eval_end_to_end[_fdtd]")
    args = parser.parse_args()
    surveys = survey_makers(args.source, load_config().gpr, args.limit, args.half)
    if args.source == "sim":
        command = f"python -m training.eval_end_to_end --limit {args.limit}"
        out = args.out or ROOT / "models" / "eval_end_to_end"
    else:
        command = f"python -m training.eval_end_to_end --source fdtd --half {args.half}"
        name = "eval_end_to_end_fdtd" if args.half == "test" else f"eval_end_to_end_fdtd_{args.half}"
        out = args.out or ROOT / "models" / name
    result = evaluate(surveys, args.source)
    if args.source == "fdtd":
        result["half"] = args.half
    out.with_suffix(".json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    text = markdown(result, command)
    out.with_suffix(".md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
