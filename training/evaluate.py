"""Tables I and II and latencies for the completion models, on the held-out test split.

    python -m training.evaluate --out models/

These are component scores: every model's input is the test sample's sparse cloud, registered from
degraded *truth* masks (training.pointcloud_data), not from interpreted B-scans — so they measure the
completion alone. The whole chain from B-scans is training.eval_end_to_end. Cached rows are keyed on the
code version (training.code_version: the data generator, the scoring and the models' sources) and the
ONNX file's bytes, so a change to any of them re-scores.

Table I: CD2×10³, CD1×10², F-score@1 % (unit-cube clouds, DESIGN §6) for GPRNet, PCN, PF-Net (the
exported ONNX files, run with onnxruntime), the geometric fit (gprbot's geometric_completion on the
same slices), the sparse input itself and the sampling floor (a second independent draw of the truth) —
overall and per case.
Table II: GPRNet with Gaussian noise σ (normalised units) on its input. Latency: median of
LATENCY_RUNS single-sample calls, onnxruntime vs PyTorch eager, both on 2 threads. When
training.eval_migration exists its MigrationNet table goes into the same report.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort
import torch
from numpy.typing import NDArray

from gprbot.config import ReconstructionConfig
from gprbot.infer.gprnet import INPUT_NAME
from gprbot.infer.onnx_model import card_path_for
from gprbot.infer.refine import FitRefinerModel, refined_reconstruction
from gprbot.motion.planner import survey_region
from gprbot.progress import track
from gprbot.reconstruct.completion import geometric_completion
from gprbot.sim.truth import sample_pipe_interiors
from training.chamfer import cloud_metrics
from training.code_version import code_version
from training.pointcloud_data import CACHE_DIR, DENSE_POINTS, load_split, survey_slices
from training.pointcloud_models import BUILDERS, GPRNet
from training.random_scenes import CASES, scene_for_seed, split_seeds

# models/<name>.onnx, those present: the shipped GPRNet, its ablation variants, the two baselines
LEARNED = ("gprnet", "gprnet_fc_seeds", "pcn", "pfnet")
NOISE_LEVELS = (0.0, 0.01, 0.05, 0.1, 0.2)
LATENCY_RUNS = 20
THREADS = 2
_ME = "training.evaluate"  # this module's name, also when run as __main__
Cloud = NDArray[np.float32]


def onnx_session(path: Path) -> ort.InferenceSession:
    """An onnxruntime session on 2 intra-op threads, as the runtime uses."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = THREADS
    options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def summarise(rows: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Mean CD2×10³, CD1×10², F-score and count, overall and per case."""
    out: dict[str, dict[str, float]] = {}
    for case in ("all", *CASES):
        chosen = [r for r in rows if case == "all" or r["case"] == case]
        if chosen:
            out[case] = {"cd2_e3": 1e3 * float(np.mean([r["cd2"] for r in chosen])),
                         # a few samples with a tiny unit cube rule the mean; the median shows the typical one
                         "median_cd2_e3": 1e3 * float(np.median([r["cd2"] for r in chosen])),
                         "cd1_e2": 1e2 * float(np.mean([r["cd1"] for r in chosen])),
                         "fscore": float(np.mean([r["fscore"] for r in chosen])), "n": len(chosen)}
    return out


def score(predict: Callable[[int], Cloud], data: dict[str, Any]) -> list[dict[str, Any]]:
    """Metrics of predict(sample index) against each test sample's truth."""
    rows = []
    for i in track(range(len(data["seed"])), "scoring", unit="sample"):
        m = cloud_metrics(predict(i), data["dense"][i])
        rows.append({"seed": int(data["seed"][i]), "case": str(data["case"][i]), "cd2": m.cd2, "cd1": m.cd1,
                     "fscore": m.fscore})
    return rows


def geometric_prediction(data: dict[str, Any], failures: list[int]) -> Callable[[int], Cloud]:
    """The geometric fit's dense cloud in the sample's unit cube (the sparse input where it finds no pipe)."""

    def predict(i: int) -> Cloud:
        seed = int(data["seed"][i])
        slices, _ = survey_slices(seed)
        recon = geometric_completion(slices, ReconstructionConfig(), np.random.default_rng(seed))
        if len(recon.dense) == 0:
            failures.append(seed)
            return np.asarray(data["sparse"][i])
        return np.asarray((recon.dense - data["centre"][i]) / data["scale"][i], dtype=np.float32)

    return predict


def refined_prediction(data: dict[str, Any], model_path: Path | None) -> Callable[[int], Cloud]:
    """The refined completion's cloud (the FitRefiner at model_path; None: every pipe continued by rule)."""
    model = None if model_path is None else FitRefinerModel(model_path, threads=THREADS)

    def predict(i: int) -> Cloud:
        seed = int(data["seed"][i])
        slices, region = survey_slices(seed)
        sparse = np.asarray(data["sparse"][i], dtype=np.float64) * data["scale"][i] + data["centre"][i]
        recon = refined_reconstruction(slices, sparse, region, ReconstructionConfig(), model,
                                       np.random.default_rng(seed))
        if len(recon.dense) == 0:
            return np.asarray(data["sparse"][i])
        return np.asarray((recon.dense - data["centre"][i]) / data["scale"][i], dtype=np.float32)

    return predict


def truth_floor(data: dict[str, Any]) -> Callable[[int], Cloud]:
    """A second, independent draw of the truth: the Chamfer distance no completion can beat on average."""

    def predict(i: int) -> Cloud:
        seed = int(data["seed"][i])
        scene, spec = scene_for_seed(seed)
        region = survey_region(spec.start_xy, spec.length_m, spec.lines, spec.spacing_m,
                               across_margin_m=0.5 * spec.spacing_m)
        points, _ = sample_pipe_interiors(scene, DENSE_POINTS, np.random.default_rng([seed, 99]), region)
        return np.asarray((points - data["centre"][i]) / data["scale"][i], dtype=np.float32)

    return predict


def onnx_prediction(session: ort.InferenceSession, data: dict[str, Any], sigma: float) -> Callable[[int], Cloud]:
    """The model's dense output for a test sample, with N(0, σ²) noise (seeded) on the normalised input."""

    def predict(i: int) -> Cloud:
        x = np.asarray(data["sparse"][i], dtype=np.float32)
        if sigma > 0.0:
            x = x + np.random.default_rng([int(data["seed"][i]), 7]).normal(0.0, sigma, x.shape).astype(np.float32)
        return np.asarray(session.run(None, {INPUT_NAME: x[None]})[0][0])

    return predict


def latency_ms(call: Callable[[], object]) -> float:
    """Median wall time (ms) of LATENCY_RUNS calls after two warm-ups."""
    call()
    call()
    times = []
    for _ in range(LATENCY_RUNS):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def checkpoint_of(onnx_path: Path) -> Path | None:
    """The training checkpoint an ONNX file was exported from, as its model card records it (if still here)."""
    card = onnx_path.with_suffix(".json")
    if not card.exists():
        return None
    recorded = Path(json.loads(card.read_text()).get("training", {}).get("checkpoint", ""))
    return recorded if recorded.is_file() else None


def latencies(name: str, session: ort.InferenceSession, x: Cloud, checkpoint: Path | None) -> dict[str, float | None]:
    """onnxruntime and (when its checkpoint is here) PyTorch-eager latency of one single-sample call."""
    out: dict[str, float | None] = {"onnxruntime_ms": latency_ms(lambda: session.run(None, {INPUT_NAME: x[None]}))}
    out["torch_eager_ms"] = None
    if checkpoint is not None:
        state = torch.load(checkpoint, weights_only=False)
        model = BUILDERS[name.split("_")[0]](**state["model_config"]).eval()
        model.load_state_dict(state["model"])
        torch.set_num_threads(THREADS)
        tensor = torch.from_numpy(x[None])
        with torch.no_grad():
            out["torch_eager_ms"] = latency_ms(lambda: model(tensor))
    return out


def migration_report(models_dir: Path) -> dict[str, Any] | None:
    """MigrationNet's evaluation from training.eval_migration (when it and the model exist), cached by version."""
    model = models_dir / "migrationnet.onnx"
    try:
        module = importlib.import_module("training.eval_migration")
    except ModuleNotFoundError:
        return None
    if not model.exists():
        return None
    cache = CACHE_DIR / f"eval_migration_{code_version(['training.eval_migration'], [model])}.json"
    if cache.exists():
        return dict(json.loads(cache.read_text()))
    result = module.evaluate_migration(split_seeds("test"), model, THREADS)
    report = result if isinstance(result, dict) else {"report": str(result)}
    cache.write_text(json.dumps(report, default=str))
    return report


def cached_rows(
    onnx_path: Path, sigma: float, data: dict[str, Any], compute: Callable[[], list[dict[str, Any]]],
    also: Sequence[Path] = (),
) -> list[dict[str, Any]]:
    """Per-sample rows of one model at one noise level, cached by the code version (with the ONNX file and the
    files `also` names: a card whose settings the runtime reads)."""
    cache = CACHE_DIR / f"eval_rows_{code_version([_ME], [onnx_path, *also])}_{sigma}_{len(data['seed'])}.json"
    if cache.exists():
        return list(json.loads(cache.read_text()))
    rows = compute()
    cache.write_text(json.dumps(rows))
    return rows


def reference_rows(data: dict[str, Any]) -> dict[str, Any]:
    """Table I rows of the geometric fit, the truth floor and the sparse input (cached by the code version)."""
    seeds = [int(x) for x in data["seed"]]
    cache = CACHE_DIR / f"eval_reference_{code_version([_ME])}_{len(seeds)}.json"
    if cache.exists():
        cached = json.loads(cache.read_text())
        if cached["seeds"] == seeds:
            return dict(cached["rows"])
    failures: list[int] = []
    geometric = score(geometric_prediction(data, failures), data)
    rows = {"geometric_no_pipe_seeds": failures,
            "per_sample_reference": {"geometric": geometric,
                                     "extended": score(refined_prediction(data, None), data),
                                     "truth_floor": score(truth_floor(data), data),
                                     "sparse_copy": score(lambda i: np.asarray(data["sparse"][i]), data)}}
    cache.write_text(json.dumps({"seeds": seeds, "rows": rows}))
    return rows


def rescore_fit_rows(report: dict[str, Any], models_dir: Path) -> dict[str, Any]:
    """The report with only the fit-based rows scored again (geometric, rule, FitRefiner) and the rest kept.

    The networks' rows depend on their ONNX files and the samples alone, not on the geometric fit's code, so a
    change to the fit re-scores these rows without the seed runs' checkpoints (kept out of the repository).
    """
    data = {k: v[:report["test_samples"]] for k, v in load_split("test").items()}
    report["fit_rows_rescored"] = code_version([_ME])
    return _score_fit_rows(report, data, models_dir)


def _score_fit_rows(report: dict[str, Any], data: dict[str, Any], models_dir: Path) -> dict[str, Any]:
    """Score the FitRefiner, the geometric fit, the rule and the reference rows into the report."""
    refiner = models_dir / "fit_refiner.onnx"
    if refiner.exists():
        rows = cached_rows(refiner, 0.0, data, lambda: score(refined_prediction(data, refiner), data),
                           also=[card_path_for(refiner)])  # its pipe threshold
        report["table1"]["fit_refiner"], report["per_sample"]["fit_refiner"] = summarise(rows), rows
    reference = reference_rows(data)
    report["geometric_no_pipe_seeds"] = reference["geometric_no_pipe_seeds"]
    for name, rows in reference["per_sample_reference"].items():
        report["table1"][name] = summarise(rows)
        if name != "truth_floor":  # the baselines each model's standing is stated against
            report["per_sample"][name] = rows
    return report


def evaluate(
    models_dir: Path, limit: int | None = None, *, with_migration: bool = True, extra: dict[str, Path] | None = None
) -> dict[str, Any]:
    """Every table of the completion evaluation as one JSON-able dict (extra: more ONNX models by name)."""
    data = {k: v[:limit] for k, v in load_split("test").items()}
    report: dict[str, Any] = {"test_samples": len(data["seed"]), "table1": {}, "table2": {}, "latency": {},
                              "training": {}, "per_sample": {}}
    paths = {n: models_dir / f"{n}.onnx" for n in LEARNED if (models_dir / f"{n}.onnx").exists()} | (extra or {})
    sessions = {n: onnx_session(p) for n, p in paths.items()}
    for name, session in sessions.items():
        for sigma in NOISE_LEVELS if name.startswith("gprnet") else (0.0,):
            predict = onnx_prediction(session, data, sigma)
            rows = cached_rows(paths[name], sigma, data, lambda p=predict: score(p, data))
            if sigma == 0.0:
                report["table1"][name], report["per_sample"][name] = summarise(rows), rows
            if name.startswith("gprnet"):
                report["table2"].setdefault(name, {})[str(sigma)] = summarise(rows)["all"]
        x0 = np.asarray(data["sparse"][0], dtype=np.float32)
        report["latency"][name] = latencies(name, session, x0, checkpoint_of(paths[name]))
        report["training"][name] = training_summary(paths[name])
    report = _score_fit_rows(report, data, models_dir)  # the fit-conditioned completion and the baselines
    report["migrationnet"] = migration_report(models_dir) if with_migration else None
    return report


NAMES = {"gprnet": "GPRNet (shipped)", "gprnet_fc_seeds": "GPRNet encoder + PCN's one-FC decoder (ablation)",
         "pcn": "PCN", "pfnet": "PF-Net",
         "fit_refiner": "refined fit (FitRefiner)", "extended": "fit continued to the survey's edge (rule)",
         "geometric": "geometric fit", "truth_floor": "truth resample (floor)",
         "sparse_copy": "sparse input as the answer"}


def training_summary(onnx_path: Path) -> dict[str, Any]:
    """Parameters, epochs, minutes, best val CD2 and ONNX size of a model, from its checkpoint."""
    checkpoint = checkpoint_of(onnx_path)
    summary: dict[str, Any] = {"onnx_mb": round(onnx_path.stat().st_size / 1e6, 2), "checkpoint": str(checkpoint)}
    if checkpoint is None:
        return summary
    state = torch.load(checkpoint, weights_only=False)
    # best.pt holds the history up to the best epoch; the whole run's is written beside it at the end
    whole_run = checkpoint.parent / "history.json"
    history = json.loads(whole_run.read_text()) if whole_run.exists() else state.get("history", [])
    return summary | {
        "parameters": int(sum(v.numel() for v in state["model"].values())),
        "model_config": state["model_config"], "best_epoch": state["epoch"], "epochs": len(history),
        "minutes": round(history[-1]["elapsed_s"] / 60.0, 1) if history else None,
        "best_val_cd2_e3": 1e3 * state.get("metrics", {}).get("val_cd2", float("nan")),
        "val_cd2_e3_curve": [round(1e3 * h["val_cd2"], 3) for h in history],
    }


def describe_variant(name: str, config: dict[str, Any]) -> str:
    """A model config in words for the training table (GPRNet's options; the baselines' sizes are below it)."""
    if not name.startswith("gprnet"):
        return "as published (sizes below)"
    defaults = {k: p.default for k, p in inspect.signature(GPRNet.__init__).parameters.items()
                if p.default is not inspect.Parameter.empty}
    cfg = defaults | config  # a checkpoint's config names only what differs from GPRNet's defaults
    fuse = cfg["fuse_hidden"]
    parts = [f"fused layer {cfg['global_dim']} wide (paper)" if fuse == 0
             else f"fused layer via a {fuse}-wide bottleneck"]
    widths = cfg["branch_widths"]
    parts.append(f"branches off FC {'/'.join(str(w) for w in widths)}" if widths
                 else f"branches off one FC {cfg['decoder_hidden']}")
    if cfg["input_seeds"]:
        parts.append(f"input-anchored ({cfg['input_seeds']} seeds)")
    return ", ".join(parts)


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def markdown(report: dict[str, Any]) -> str:
    """The report as Markdown tables (Table I overall and per case, Table II, latency, training)."""
    t1 = report["table1"]
    lines = [f"# Completion evaluation ({report['test_samples']} held-out test scenes): component scores from "
             "degraded truth masks", "",
             "Every model here is fed the test sample's sparse cloud registered from degraded **truth masks** "
             "(training.pointcloud_data: the true cross-sections with dropped and speckled pixels), not from "
             "interpreted B-scans: these tables score the completion alone. End to end from simulated and FDTD "
             "B-scans, velocity estimated, see eval_end_to_end.md and eval_end_to_end_fdtd.md.", "",
             "Clouds normalised to the unit cube (DESIGN §6); CD2×10³, CD1×10², F-score at 0.01.", "",
             *([f"The fit-based rows (geometric fit, rule, FitRefiner) were scored again at code version "
                f"{report['fit_rows_rescored']} (`python -m training.evaluate --fit-rows-only`); the networks' rows, "
                "latencies and training figures are the last full run's (`python -m training.evaluate`).", ""]
               if report.get("fit_rows_rescored") else []),
             "## Table I — overall", "", _row(["method", "CD2×10³", "median CD2×10³", "CD1×10²", "F@1%"]),
             _row(["---"] * 5)]
    for name, tables in t1.items():
        a = tables["all"]
        lines.append(_row([NAMES.get(name, name), f"{a['cd2_e3']:.3f}", f"{a['median_cd2_e3']:.3f}",
                           f"{a['cd1_e2']:.3f}", f"{a['fscore']:.3f}"]))
    lines += ["", "## Table I — per case (CD2×10³ / F@1%)", "", _row(["method", *CASES]), _row(["---"] * 7)]
    for name, tables in t1.items():
        cells = [f"{tables[c]['cd2_e3']:.2f} / {tables[c]['fscore']:.2f}" if c in tables else "-" for c in CASES]
        lines.append(_row([NAMES.get(name, name), *cells]))
    lines += ["", "## Table II — Gaussian noise σ on the normalised input (CD2×10³ / CD1×10² / F@1%)", "",
              _row(["model", *(f"σ={s}" for s in NOISE_LEVELS)]), _row(["---"] * (1 + len(NOISE_LEVELS)))]
    for name, by_sigma in report["table2"].items():
        cells = [f"{v['cd2_e3']:.2f} / {v['cd1_e2']:.2f} / {v['fscore']:.2f}" for v in by_sigma.values()]
        lines.append(_row([NAMES.get(name, name), *cells]))
    lines += ["", f"## Latency (one sample, median of {LATENCY_RUNS}, {THREADS} threads)", "",
              _row(["model", "onnxruntime ms", "PyTorch eager ms"]), _row(["---"] * 3)]
    for name, lat in report["latency"].items():
        eager = "-" if lat["torch_eager_ms"] is None else f"{lat['torch_eager_ms']:.1f}"
        lines.append(_row([NAMES.get(name, name), f"{lat['onnxruntime_ms']:.1f}", eager]))
    if report.get("training"):
        lines += ["", "## Training", "", _row(["model", "variant", "parameters", "epochs", "minutes", "best epoch",
                                               "best val CD2×10³", "ONNX MB"]), _row(["---"] * 8)]
        for name, t in report["training"].items():
            cells = [str(t.get(k, "-")) for k in ("parameters", "epochs", "minutes", "best_epoch")]
            variant = describe_variant(name, t.get("model_config", {}))
            lines.append(_row([NAMES.get(name, name), variant, *cells, f"{t.get('best_val_cd2_e3', float('nan')):.3f}",
                               str(t["onnx_mb"])]))
    lines += ["", "## Standing against the baselines (per test sample, CD2)", "", *standing_lines(report)]
    lines += [*seed_lines(report), *targets(report), "", REDUCTIONS]
    lines += ["", f"Geometric fit found no pipe (scored on its sparse input) for seeds: "
              f"{report['geometric_no_pipe_seeds'] or 'none'}."]
    if report.get("migrationnet") is not None:
        lines += ["", "## MigrationNet (training.eval_migration)", "", "```json",
                  json.dumps(report["migrationnet"], indent=1, default=str), "```"]
    return "\n".join(lines) + "\n"


REDUCTIONS = """## Sizes vs the paper (2-core CPU budget)

* GPRNet: encoder 64/128/256 with max-pools as in the paper, then the paper's one fused PointNet layer on
  [point features; all pooled globals] (448 + 448 wide) straight to the 896-d global vector. Decoder: FC
  branches for 256/128/64 points off one shared FC 512, plus the global vector reshaped by an MLP into
  448 = 896 seeds, a folding MLP 128 wide around each seed (3×3 grid) → 8064 points (the paper's count).
  The ablation "GPRNet encoder + PCN's one-FC decoder" keeps that encoder and makes all 896 seeds with one
  FC layer off the shared 512 one, as PCN's coarse decoder does: what the decoder's branches are worth.
* PCN: encoder 128-256 / 256-512 (paper 128-256 / 512-1024), 896 coarse points, 3×3 fold, folding
  MLP 128 wide (paper 4×4 fold of 1024 coarse points, 512 wide).
* PF-Net: three resolutions by striding the (already random) input instead of farthest-point sampling,
  CMLP 64-128-256, latent 512, pyramid 112 → 896 → 8064, predicting the whole cloud (PF-Net predicts
  the missing part only).
* Training: every model gets the same budget and the same recipe (scripts/train_completion_models.sh): 6
  epochs of the first 600 training samples, batch 8, Adam 1e-3 with a cosine over the steps, loss = CD2 over
  the model's stages on random 2048-point subsets, the best validation epoch kept; seeds 0, 1, 2 (seed 0 is
  the shipped file, the others are scored as NAME_s1, NAME_s2). A budget in epochs makes the result the
  command's, not the machine's. The paper trains for hundreds of epochs on a GPU; these models are far from
  converged (validation CD2 still falling at the last epoch), so the tables compare the architectures at
  this budget, not at convergence. The earlier shipped models had 11–16 epochs of all 1378 samples on a
  wall-clock budget that no command reproduced (GPRNet's best validation CD2 then 4.13×10⁻³).
* Two training samples whose truth lies > 1.5 cube widths outside their sparse cloud are left out of
  training (seeds 323, 353: a speckle blob on one line made the cube tiny; one such sample's loss was
  ~10³ times a normal one and swamped the gradient of every epoch). The test split has none.
"""


BASELINES = ("sparse_copy", "geometric")


def standing(report: dict[str, Any]) -> dict[str, dict[str, dict[str, float]]]:
    """Each scored model against each baseline: on how many test samples its CD2 is lower, and both means
    and medians — from the per-sample rows, so tests/test_shipped_completion.py can check them."""
    per = report["per_sample"]
    out: dict[str, dict[str, dict[str, float]]] = {}
    for name in (n for n in per if n not in BASELINES):
        mine = {r["seed"]: r["cd2"] for r in per[name]}
        for base in (b for b in BASELINES if b in per):
            theirs = {r["seed"]: r["cd2"] for r in per[base]}
            seeds = [k for k in mine if k in theirs]
            a, b = np.array([mine[k] for k in seeds]), np.array([theirs[k] for k in seeds])
            out.setdefault(name, {})[base] = {
                "closer": int(np.sum(a < b)), "samples": len(seeds), "mean_e3": 1e3 * float(np.mean(a)),
                "base_mean_e3": 1e3 * float(np.mean(b)), "median_e3": 1e3 * float(np.median(a)),
                "base_median_e3": 1e3 * float(np.median(b))}
    return out


def standing_lines(report: dict[str, Any]) -> list[str]:
    """The standing as EVAL.md states it, one line per model and baseline."""
    def word(x: float, y: float) -> str:
        return "better" if x < y else "worse"

    lines = []
    for name, bases in standing(report).items():
        for base, s in bases.items():
            lines.append(
                f"* {NAMES.get(name, name)} vs {NAMES[base]}: lower CD2 on {s['closer']} of {s['samples']} samples; "
                f"mean CD2×10³ {s['mean_e3']:.3f} vs {s['base_mean_e3']:.3f} "
                f"({word(s['mean_e3'], s['base_mean_e3'])}), "
                f"median {s['median_e3']:.3f} vs {s['base_median_e3']:.3f} "
                f"({word(s['median_e3'], s['base_median_e3'])})")
    return lines


SEEDED = ("gprnet", "pcn", "pfnet")  # the paper's comparison; seed k > 0 is scored as NAME_sK (--extra)


def seed_suffix(name: str, model: str) -> str | None:
    """"" for the model's shipped run (NAME), "_sK" for its seed K (NAME_sK), None for any other name."""
    if name == model:
        return ""
    return name[len(model):] if name.startswith(f"{model}_s") and name[len(model) + 2:].isdigit() else None


def seed_runs(report: dict[str, Any]) -> dict[str, list[str]]:
    """The scored runs of each compared model: NAME (seed 0, shipped) and NAME_s1, NAME_s2, ..."""
    t1 = report["table1"]
    return {m: [n for n in t1 if seed_suffix(n, m) is not None] for m in SEEDED}


def seed_lines(report: dict[str, Any]) -> list[str]:
    """Per model its mean and median CD2 over seeds (min–max), and GPRNet / PCN per seed pair."""
    runs, t1 = seed_runs(report), report["table1"]
    if not all(len(v) >= 2 for v in runs.values()):
        return []
    lines = ["", "## Seeds (the paper's comparison at an equal epoch budget)", "",
             _row(["model", "seeds", "mean CD2×10³ (min–max)", "median CD2×10³ (min–max)"]), _row(["---"] * 4)]
    for model, names in runs.items():
        means = [t1[n]["all"]["cd2_e3"] for n in names]
        medians = [t1[n]["all"]["median_cd2_e3"] for n in names]
        lines.append(_row([NAMES.get(model, model), str(len(names)),
                           f"{np.mean(means):.3f} ({min(means):.3f}–{max(means):.3f})",
                           f"{np.mean(medians):.3f} ({min(medians):.3f}–{max(medians):.3f})"]))
    pairs = list(zip(runs["gprnet"], runs["pcn"], strict=False))
    ratios = [t1[g]["all"]["cd2_e3"] / t1[p]["all"]["cd2_e3"] for g, p in pairs]
    medians = [t1[g]["all"]["median_cd2_e3"] / t1[p]["all"]["median_cd2_e3"] for g, p in pairs]
    verdict = "met" if np.mean(ratios) <= 0.89 else "NOT met"
    lines += ["", f"GPRNet / PCN mean CD2, seed by seed: {', '.join(f'{r:.3f}' for r in ratios)} — mean "
              f"{np.mean(ratios):.3f}, spread {min(ratios):.3f}–{max(ratios):.3f} (target ≤ 0.89: {verdict}); by the "
              f"median CD2: {', '.join(f'{r:.3f}' for r in medians)}."]
    return lines


def targets(report: dict[str, Any]) -> list[str]:
    """The brief's targets, each marked met or not, for every GPRNet variant scored.

    A seed's GPRNet (gprnet_sK) is set against the baselines of the same seed (pcn_sK, pfnet_sK): a ratio across
    seeds would measure the seeds' spread, not the models."""
    t1 = report["table1"]
    out = ["", "## Targets"]
    for g_name in (n for n in t1 if n.startswith("gprnet")):
        g = t1[g_name]["all"]["cd2_e3"]
        label = NAMES.get(g_name, g_name)
        seed = seed_suffix(g_name, "gprnet") or ""  # an ablation (not a seed) is set against seed 0's
        for base, bar in ((f"pcn{seed}", 0.89), (f"pfnet{seed}", 1.0)):
            if base in t1:
                ratio = g / t1[base]["all"]["cd2_e3"]
                verdict = "met" if ratio <= bar else "NOT met"
                out.append(f"* {label} CD2 / {NAMES.get(base, base)} CD2 = {ratio:.3f} (target ≤ {bar}): {verdict}")
        better = [c for c in CASES if c in t1[g_name] and t1[g_name][c]["cd2_e3"] < t1["geometric"][c]["cd2_e3"]]
        out.append(f"* {label} beats the geometric fit on CD2 in: {', '.join(better) or 'no case'}")
    for name, lat in report["latency"].items():
        ms = lat["onnxruntime_ms"]
        verdict = "met" if ms <= 100 else "NOT met"
        out.append(f"* {NAMES.get(name, name)} onnxruntime {ms:.1f} ms (target ≤ 100 ms): {verdict}")
    return out


def main() -> None:
    """Run the evaluation and write eval_completion.json and EVAL.md into --out."""
    parser = argparse.ArgumentParser(description="evaluate the completion models (Tables I and II)")
    parser.add_argument("--out", type=Path, default=Path("models"))
    parser.add_argument("--limit", type=int, default=None, help="only the first N test samples")
    parser.add_argument("--extra", nargs="*", default=[], help="more models to score, as NAME=PATH.onnx")
    parser.add_argument("--no-migration", action="store_true", help="leave out MigrationNet's table")
    parser.add_argument("--fit-rows-only", action="store_true",
                        help="score only the fit-based rows again, keeping the recorded networks' rows")
    args = parser.parse_args()
    extra = dict((n, Path(p)) for n, p in (item.split("=", 1) for item in args.extra))
    if args.fit_rows_only:
        report = rescore_fit_rows(json.loads((args.out / "eval_completion.json").read_text()), args.out)
    else:
        report = evaluate(args.out, args.limit, with_migration=not args.no_migration, extra=extra)
    (args.out / "eval_completion.json").write_text(json.dumps(report, indent=1, default=str))
    text = markdown(report)
    (args.out / "EVAL.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
