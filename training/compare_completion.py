"""The paper's comparison at a larger budget on one machine: GPRNet, PCN and PF-Net × seeds, trained at once.

    python -m training.compare_completion --epochs 40 --device cuda --jobs 16 --deadline-min 8 --out DIR

Generates the completion splits (in `--jobs` processes; skipped when cached), starts every run of
RUNS × seeds together (training.train_completion, each its own process, all on `--device`), stops any
still running at the deadline, then scores every run's best checkpoint on the test split with the same
metrics as training.evaluate (component scores: degraded truth masks in, not interpreted B-scans) and
writes DIR/compare_completion.{json,md}. Every run has the same epoch budget and all the training
samples; a run stopped by the deadline is reported as such (its cosine schedule did not finish).
The shipped CPU models and models/EVAL.md are untouched: this is the budget check the CPU can't afford.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from training.evaluate import _row, score, seed_lines, summarise
from training.pointcloud_data import load_split
from training.pointcloud_models import BUILDERS
from training.random_scenes import CASES
from training.train_completion import CHECKPOINTS, LOGS

RUNS = (("gprnet", "gprnet_fullfuse"), ("pcn", "pcn"), ("pfnet", "pfnet"))  # (model, variant), as shipped


def run_name(variant: str, epochs: int, seed: int, device: str) -> str:
    """A run's checkpoint and log name."""
    return f"{variant}_e{epochs}_s{seed}_{device}"


def report_name(model: str, variant: str, seed: int) -> str:
    """The name training.evaluate's seed lines expect: NAME for seed 0, NAME_sK for the others (NAME is the
    model for the paper's runs, the variant for an ablation)."""
    name = model if (model, variant) in RUNS else variant
    return name if seed == 0 else f"{name}_s{seed}"


def start_run(model: str, variant: str, epochs: int, seed: int, device: str,
              train_limit: int | None) -> subprocess.Popen[bytes]:
    """One training process, its output to training/logs/<run>.out."""
    name = run_name(variant, epochs, seed, device)
    LOGS.mkdir(parents=True, exist_ok=True)
    out = (LOGS / f"{name}.out").open("wb")
    command = [sys.executable, "-m", "training.train_completion", "--model", model, "--variant", variant,
               "--name", name, "--epochs", str(epochs), "--seed", str(seed), "--device", device, "--threads", "1"]
    if train_limit is not None:
        command += ["--train-limit", str(train_limit)]
    return subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, env={**os.environ, "OMP_NUM_THREADS": "1"})


def score_run(job: tuple[str, str, str]) -> tuple[str, list[dict[str, Any]]]:
    """Test-split rows of one run's best checkpoint, run on the CPU (one thread)."""
    label, model_kind, name = job
    torch.set_num_threads(1)
    state = torch.load(CHECKPOINTS / name / "best.pt", weights_only=False, map_location="cpu")
    model = BUILDERS[model_kind](**state["model_config"])
    model.load_state_dict(state["model"])
    model.eval()
    data = load_split("test", generate=False)

    @torch.no_grad()
    def predict(i: int) -> Any:
        return model(torch.from_numpy(np.asarray(data["sparse"][i:i + 1], dtype=np.float32)))[0].numpy()

    return label, score(predict, data)


def history_of(name: str) -> list[dict[str, float]]:
    """A run's per-epoch history from its last checkpoint ([] when it never finished an epoch)."""
    last = CHECKPOINTS / name / "last.pt"
    return torch.load(last, weights_only=False, map_location="cpu")["history"] if last.exists() else []


def markdown(report: dict[str, Any]) -> str:
    """The comparison as a markdown page."""
    t1, runs = report["table1"], report["runs"]
    lines = [f"# GPRNet vs PCN vs PF-Net at {report['epochs']} epochs on {report['device']} "
             f"({report['train_samples']} training samples, {report['seeds']} seeds)", "",
             "Component scores on the 150-scene test split: the inputs are sparse clouds registered from degraded "
             "truth masks (training.pointcloud_data), as in EVAL.md, not interpreted B-scans. CD2×10³, CD1×10², "
             f"F@1 %. Made by `python -m training.compare_completion` ({report['command']}); machine: "
             f"{report['machine']}.", "",
             _row(["run", "epochs done", "train min", "best val CD2×10³", "CD2×10³", "median CD2×10³", "CD1×10²",
                   "F@1%"]), _row(["---"] * 8)]
    for label, run in runs.items():
        a = t1[label]["all"]
        lines.append(_row([label, f"{run['epochs_done']}/{report['epochs']}", f"{run['minutes']:.1f}",
                           f"{run['best_val_cd2_e3']:.3f}", f"{a['cd2_e3']:.3f}", f"{a['median_cd2_e3']:.3f}",
                           f"{a['cd1_e2']:.3f}", f"{a['fscore']:.3f}"]))
    lines += ["", "Per case (mean CD2×10³):", "", _row(["run", *CASES]), _row(["---"] * (len(CASES) + 1))]
    lines += [_row([label, *(f"{t1[label][c]['cd2_e3']:.2f}" for c in CASES)]) for label in runs]
    lines += [line.replace(" (shipped)", "") for line in seed_lines(report)]  # these runs are not shipped
    return "\n".join(lines) + "\n"


def main() -> None:
    """Generate, train every run at once, score, write the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=40)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--deadline-min", type=float, default=8.0, help="stop runs still going after this long")
    parser.add_argument("--train-limit", type=int, default=None, help="fewer training samples (a smoke run)")
    parser.add_argument("--runs", nargs="*", default=[f"{m}:{v}" for m, v in RUNS],
                        help="MODEL:VARIANT pairs (default: the paper's comparison; e.g. gprnet:gprnet_fc_seeds)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    runs = [tuple(pair.split(":", 1)) for pair in args.runs]
    args.out.mkdir(parents=True, exist_ok=True)
    begin = time.perf_counter()
    for split in ("train", "val", "test"):
        n = len(load_split(split, jobs=args.jobs)["seed"])
        print(f"{split}: {n} samples at {time.perf_counter() - begin:.0f} s", flush=True)
    jobs = {(model, variant, seed): start_run(model, variant, args.epochs, seed, args.device, args.train_limit)
            for seed in range(args.seeds) for model, variant in runs}
    deadline = time.perf_counter() + 60.0 * args.deadline_min
    for proc in jobs.values():
        try:
            proc.wait(timeout=max(deadline - time.perf_counter(), 1.0))
        except subprocess.TimeoutExpired:
            proc.terminate()
    print(f"training over at {time.perf_counter() - begin:.0f} s", flush=True)
    labels = {report_name(m, v, s): (m, run_name(v, args.epochs, s, args.device)) for m, v, s in jobs
              if (CHECKPOINTS / run_name(v, args.epochs, s, args.device) / "best.pt").exists()}
    with multiprocessing.get_context("spawn").Pool(min(len(labels), args.jobs)) as pool:
        scored = dict(pool.map(score_run, [(label, m, name) for label, (m, name) in labels.items()]))
    runs = {}
    for label, (_, name) in sorted(labels.items()):
        history = history_of(name)
        runs[label] = {"run": name, "epochs_done": len(history), "minutes": history[-1]["elapsed_s"] / 60 if history
                       else 0.0, "best_val_cd2_e3": 1e3 * min(h["val_cd2"] for h in history) if history else
                       float("nan"), "history": history}
    report = {"epochs": args.epochs, "seeds": args.seeds, "device": args.device,
              "machine": f"{torch.cuda.get_device_name() if args.device == 'cuda' else 'cpu'}, {os.cpu_count()} "
                         f"cores, torch {torch.__version__}",
              "command": " ".join(sys.argv[1:]), "train_samples": args.train_limit or len(load_split("train")["seed"]),
              "table1": {label: summarise(rows) for label, rows in scored.items()},
              "per_sample": scored, "runs": runs, "total_s": time.perf_counter() - begin}
    (args.out / "compare_completion.json").write_text(json.dumps(report, indent=1))
    (args.out / "compare_completion.md").write_text(markdown(report))
    print(markdown(report), flush=True)


if __name__ == "__main__":
    main()
