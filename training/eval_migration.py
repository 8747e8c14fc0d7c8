"""MigrationNet vs the classical path (interpret_bscan: hyperbola fits + Kirchhoff migration) on held-out scenes.

    python -m training.eval_migration --model models/migrationnet.onnx \
        --checkpoint training/checkpoints/migrationnet_best.pt          # writes models/migrationnet_eval.{md,json}

Both methods get the same preprocessed lines and the true velocity (eps_r known), so the comparison
is of interpretation alone. Each method's mask is scored against the true cross-section mask on its
own grid (gprbot.sim.truth): pixel IoU, precision, recall pooled over all lines, and per case. True
pipe crossings are the true mask's blobs; a detection within 10 cm along track matches one, and its
position and centre-depth errors are reported.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from gprbot.config import InterpretationConfig
from gprbot.errors import GprbotError
from gprbot.gpr.bscan import CrossSection, Detection
from gprbot.gpr.interpret import interpret_bscan
from gprbot.gpr.preprocess import preprocess
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.infer.migrationnet import MigrationNetInterpreter
from gprbot.progress import track
from gprbot.sim.truth import cross_section_mask
from training.migration_data import simulate_line
from training.random_scenes import CASES, gpr_config, scene_for_seed, split_seeds

LINES_PER_SCENE = 2
MATCH_DISTANCE_M = 0.10
ROOT = Path(__file__).resolve().parents[1]


def true_crossings(mask: NDArray[np.bool_], x_m: NDArray[np.float64], z_m: NDArray[np.float64]) -> list[Detection]:
    """The true mask's blobs as detections: centroid x, middle depth, half height."""
    labels, _ = ndimage.label(mask)
    found = []
    for index, region in enumerate(ndimage.find_objects(labels), start=1):
        if region is None:
            continue
        rows, cols = np.nonzero(labels[region] == index)
        z = z_m[region[0]][rows]
        found.append(Detection(float(x_m[region[1]][cols].mean()), float((z.min() + z.max()) / 2),
                               float(z.max() - z.min()) / 2, 1.0))
    return found


def match(truth: Sequence[Detection], found: Sequence[Detection]) -> list[tuple[Detection, Detection]]:
    """Greedy nearest-in-x matching within MATCH_DISTANCE_M."""
    pairs = sorted(((abs(t.x_m - f.x_m), i, j) for i, t in enumerate(truth) for j, f in enumerate(found)))
    used_t: set[int] = set()
    used_f: set[int] = set()
    matched = []
    for distance, i, j in pairs:
        if distance <= MATCH_DISTANCE_M and i not in used_t and j not in used_f:
            used_t.add(i)
            used_f.add(j)
            matched.append((truth[i], found[j]))
    return matched


class _Score:
    """Running pixel and detection counts for one method."""

    def __init__(self) -> None:
        self.tp = self.fp = self.fn = 0
        self.n_true = self.n_found = 0
        self.dx: list[float] = []
        self.dz: list[float] = []
        self.line_iou: list[float] = []

    def add(self, predicted: NDArray[np.bool_], truth: NDArray[np.bool_], section: CrossSection) -> None:
        tp = int((predicted & truth).sum())
        fp = int((predicted & ~truth).sum())
        fn = int((~predicted & truth).sum())
        self.tp, self.fp, self.fn = self.tp + tp, self.fp + fp, self.fn + fn
        if tp + fp + fn:
            self.line_iou.append(tp / (tp + fp + fn))
        crossings = true_crossings(truth, section.x_m, section.z_m)
        self.n_true += len(crossings)
        self.n_found += len(section.detections)
        for t, f in match(crossings, section.detections):
            self.dx.append(abs(t.x_m - f.x_m))
            self.dz.append(abs(t.depth_m - f.depth_m))

    def summary(self) -> dict[str, float]:
        matched = len(self.dx)
        return {
            "iou": self.tp / max(self.tp + self.fp + self.fn, 1),
            "precision": self.tp / max(self.tp + self.fp, 1),
            "recall": self.tp / max(self.tp + self.fn, 1),
            "mean_line_iou": float(np.mean(self.line_iou)) if self.line_iou else 0.0,
            "detection_recall": matched / max(self.n_true, 1),
            "detection_precision": matched / max(self.n_found, 1),
            "median_position_error_m": float(np.median(self.dx)) if self.dx else float("nan"),
            "median_depth_error_m": float(np.median(self.dz)) if self.dz else float("nan"),
            "true_crossings": self.n_true,
        }


def _truth_for(scene: Any, spec: Any, line: int, section: CrossSection) -> NDArray[np.bool_]:
    columns = np.stack([spec.start_xy[0] + section.x_m, np.full(len(section.x_m), spec.line_y(line))], axis=1)
    return cross_section_mask(scene, columns, section.z_m)


def evaluate_migration(test_seeds: Sequence[int], model_path: Path, threads: int = 2,
                       methods: Sequence[str] = ("migrationnet", "classical")) -> dict[str, Any]:
    """Score MigrationNet and the classical path on up to LINES_PER_SCENE lines of each test scene."""
    interpreter = MigrationNetInterpreter(model_path, threads)
    cfg = InterpretationConfig()
    scores: dict[str, dict[str, _Score]] = defaultdict(lambda: defaultdict(_Score))
    seconds: dict[str, list[float]] = {m: [] for m in methods}
    failures = dict.fromkeys(methods, 0)
    for seed in track(test_seeds, "scenes", unit="scene"):
        scene, spec = scene_for_seed(seed)
        case = CASES[seed % len(CASES)]
        gpr = gpr_config(spec, scene)
        v = velocity_from_eps(scene.slab.eps_r)
        rng = np.random.default_rng([seed, 2])
        kept = list(spec.kept_lines())
        for line in sorted(int(i) for i in rng.choice(kept, size=min(LINES_PER_SCENE, len(kept)), replace=False)):
            processed = preprocess(simulate_line(scene, spec, line, rng), gpr)
            for method in methods:
                start = time.perf_counter()
                try:
                    if method == "migrationnet":
                        section = interpreter.interpret(processed, gpr, cfg, v)
                    else:
                        section = interpret_bscan(processed, gpr, cfg, v)
                except GprbotError:
                    failures[method] += 1
                    continue
                seconds[method].append(time.perf_counter() - start)
                truth = _truth_for(scene, spec, line, section)
                for key in ("all", case):
                    scores[method][key].add(section.mask, truth, section)
    return {
        "test_scenes": len(test_seeds),
        "lines": len(seconds[methods[0]]) + failures[methods[0]],
        "velocity": "true (eps_r known) for both methods",
        "methods": {m: {k: s.summary() for k, s in per.items()} for m, per in scores.items()},
        "median_line_seconds": {m: statistics.median(s) for m, s in seconds.items() if s},
        "failures": failures,
        "latency": tile_latency(interpreter, threads),
    }


def tile_latency(interpreter: MigrationNetInterpreter, threads: int, runs: int = 30) -> dict[str, float]:
    """Median onnxruntime time of one 128×128 tile (batch 1) over `runs` runs."""
    from gprbot.infer.migrationnet import COLS, INPUT_NAME, ROWS

    tile = np.random.default_rng(0).standard_normal((1, 1, ROWS, COLS)).astype(np.float32)
    times = [interpreter.model.run({INPUT_NAME: tile})[1] for _ in range(runs)]
    return {"onnxruntime_tile_ms": 1000 * statistics.median(times), "threads": threads, "runs": runs}


def torch_latency(checkpoint: Path, threads: int, runs: int = 30) -> float:
    """Median PyTorch eager time (ms) of one tile, for comparison with onnxruntime."""
    import torch

    from training.migrationnet import build_migrationnet

    torch.set_num_threads(threads)
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    model = build_migrationnet(**state["model_config"])
    model.load_state_dict(state["model"])
    model.eval()
    x = torch.randn(1, 1, 128, 128)
    times = []
    with torch.no_grad():
        model(x)
        for _ in range(runs):
            start = time.perf_counter()
            model(x)
            times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def markdown(result: dict[str, Any], command: str) -> str:
    """The evaluation as a markdown report."""
    keys = ("iou", "precision", "recall", "mean_line_iou", "detection_recall", "detection_precision",
            "median_position_error_m", "median_depth_error_m")
    lines = [
        "# MigrationNet evaluation (held-out test split)", "",
        f"{result['test_scenes']} test scenes (training.random_scenes split 'test', seeds 200000-200149), "
        f"{result['lines']} lines ({LINES_PER_SCENE} per scene). Velocity: {result['velocity']}. "
        "Pixel metrics pooled over all lines on each method's own grid; detections match a true crossing "
        f"within {MATCH_DISTANCE_M * 100:.0f} cm along track.", "",
        "| method | case | " + " | ".join(keys) + " | true crossings |",
        "|---" * (len(keys) + 3) + "|",
    ]
    for method, per in result["methods"].items():
        for case in ("all", *CASES):
            if case in per:
                s = per[case]
                lines.append(f"| {method} | {case} | " + " | ".join(f"{s[k]:.3f}" for k in keys)
                             + f" | {s['true_crossings']} |")
    lat = result["latency"]
    lines += [
        "", "## Latency", "",
        f"- onnxruntime, one 128×128 tile, {lat['threads']} threads: median {lat['onnxruntime_tile_ms']:.1f} ms "
        f"({lat['runs']} runs)",
    ]
    if "torch_eager_tile_ms" in lat:
        lines.append(f"- PyTorch eager, same tile, {lat['threads']} threads: "
                     f"median {lat['torch_eager_tile_ms']:.1f} ms")
    for method, s in result["median_line_seconds"].items():
        lines.append(f"- whole line ({method}, incl. depth conversion / fitting): median {s * 1000:.0f} ms")
    lines.append(f"- interpretation failures (InterpretationError): {result['failures']}")
    if "note" in result:
        lines += ["", f"Note: {result['note']}."]
    lines += ["",
              "Machine: shared 2-core CPU (other jobs running), onnxruntime CPUExecutionProvider.", "",
              "## Reproduce", "", "```", command, "```", ""]
    return "\n".join(lines)


def main() -> None:
    """CLI: evaluate and write models/migrationnet_eval.md and .json."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, default=ROOT / "models" / "migrationnet.onnx")
    parser.add_argument("--checkpoint", type=Path, default=None, help="also time PyTorch eager")
    parser.add_argument("--limit", type=int, default=None, help="only the first N test scenes")
    parser.add_argument("--out", type=Path, default=ROOT / "models" / "migrationnet_eval")
    parser.add_argument("--reuse-classical", type=Path, default=None,
                        help="take the classical path's scores from this earlier result JSON (same seeds)")
    args = parser.parse_args()
    seeds = list(split_seeds("test"))[:args.limit]
    if args.reuse_classical is None:
        result = evaluate_migration(seeds, args.model)
    else:
        result = evaluate_migration(seeds, args.model, methods=("migrationnet",))
        earlier = json.loads(args.reuse_classical.read_text())
        result["methods"]["classical"] = earlier["methods"]["classical"]
        result["median_line_seconds"]["classical"] = earlier["median_line_seconds"]["classical"]
        result["failures"]["classical"] = earlier["failures"]["classical"]
        result["note"] = (f"classical rows from {args.reuse_classical.name}: same seeds, lines and noise (the "
                          "classical path draws nothing from the scene's generator)")
    if args.checkpoint is not None:
        result["latency"]["torch_eager_tile_ms"] = torch_latency(args.checkpoint, result["latency"]["threads"])
    command = f"python -m training.eval_migration --model {args.model} --checkpoint {args.checkpoint}" + (
        f" --limit {args.limit}" if args.limit else "")
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
    args.out.with_suffix(".md").write_text(markdown(result, command))
    print(markdown(result, command))


if __name__ == "__main__":
    main()
