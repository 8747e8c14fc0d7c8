"""Train GPRNet, PCN or PF-Net on the cached completion dataset, on a budget of epochs, with resume.

    python -m training.train_completion --model gprnet --epochs 4 --seed 0 --name gprnet_s0

Every epoch writes training/checkpoints/<name>/last.pt (model, optimizer, history, elapsed time) and,
when the validation CD2 improves, best.pt — the checkpoint tools/export_onnx.py reads. Re-running the
same command resumes from last.pt (a checkpoint written with another budget, seed or size is refused).
The budget is epochs and the learning rate follows a cosine over their steps, so two runs of one
command give the same model on any machine; the wall clock is only reported. Each epoch's shuffle and
augmentation draws come from (seed, epoch), so a resumed run continues exactly. The loss is CD2 summed
over the model's stages (coarse → dense); each step compares a random 2048-point subset of the truth
(and of the dense output) — an unbiased estimate of the pred→truth term at a quarter of the cost of the
full 8064 × 8192 matrix.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from training.chamfer import chamfer_l2, cloud_metrics
from training.pointcloud_data import load_split
from training.pointcloud_models import BUILDERS, parameter_count

ROOT = Path(__file__).resolve().parent
CHECKPOINTS = ROOT / "checkpoints"
LOGS = ROOT / "logs"
# Sizes shrunk from the paper for a 2-core CPU budget (see models/EVAL.md for what they cost).
MODEL_CONFIGS: dict[str, dict[str, Any]] = {
    "gprnet": {}, "pcn": {}, "pfnet": {}, "gprnet_anchored": {"input_seeds": 448},
    "gprnet_fullfuse": {"fuse_hidden": 0},  # the paper's fused layer at full width (no 64-wide bottleneck)
    # and its branches as a 1024/512/256 FC chain, 256/128/64 points read off successive layers
    "gprnet_pyramid": {"fuse_hidden": 0, "branch_widths": (1024, 512, 256)},
    # ablation: GPRNet's encoder with PCN's decoder (all 896 seeds from one FC layer off a 512 hidden one, no
    # branches, no reshaped global) — which half of GPRNet makes the difference against PCN
    "gprnet_fc_seeds": {"fuse_hidden": 0, "branch_points": (896,), "reshape_points": 0},
}
MIN_LR_FRACTION = 0.05
# A sample whose truth reaches this far outside the unit cube had a sparse cloud far smaller than its pipes
# (e.g. one speckle blob seen on one line: seed 353 spans 3 cm, its truth 18 cube widths). The normalisation
# cannot represent it, and its Chamfer loss (~10³ times a normal one) swamped every epoch's gradient.
MAX_TRUTH_EXTENT = 1.5
DENSE_OUT = 8064  # 896 seeds × 9: every model ends with the paper's count, not the registry's default 8192


def export_overrides() -> dict[str, Any]:
    """The checkpoint's "export" entry for tools/export_onnx.py: the dense output has 8064 points."""
    return {"outputs": [["dense_points", [DENSE_OUT, 3], "dense cloud (896 seeds × 3×3 fold) in the same "
                         "normalised frame as the input"]]}


def augment(sparse: torch.Tensor, dense: torch.Tensor, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Mirror x and/or y (lines stay along x, depth stays down) and add light input noise to some samples."""
    b = sparse.shape[0]
    signs = torch.ones(b, 1, 3)
    signs[:, 0, :2] = torch.where(torch.rand(b, 2, generator=gen) < 0.5, -1.0, 1.0)
    noisy = torch.rand(b, 1, 1, generator=gen) < 0.3
    sigma = torch.rand(b, 1, 1, generator=gen) * 0.01 * noisy
    sparse = sparse * signs + sigma * torch.randn(sparse.shape, generator=gen)
    return sparse, dense * signs


def random_subset(points: torch.Tensor, n: int, gen: torch.Generator) -> torch.Tensor:
    """n random points (without replacement) of each cloud in a batch (B, M, 3); all when M ≤ n.

    The draws come from the CPU generator wherever the points are, so a run's draws are the same on any device.
    """
    if points.shape[1] <= n:
        return points
    index = torch.stack([torch.randperm(points.shape[1], generator=gen)[:n] for _ in range(points.shape[0])])
    return torch.gather(points, 1, index.to(points.device).unsqueeze(-1).expand(-1, -1, 3))


def stage_loss(stages: list[torch.Tensor], dense: torch.Tensor, n: int, gen: torch.Generator) -> torch.Tensor:
    """Sum over stages of CD2 against a random n-point subset of the truth (the dense stage subsampled too)."""
    truth = random_subset(dense, n, gen)
    return sum((chamfer_l2(random_subset(s, n, gen), truth).mean() for s in stages),
               torch.zeros((), device=dense.device))


@torch.no_grad()
def validate(model: torch.nn.Module, sparse: NDArray[np.float32], dense: NDArray[np.float32]) -> dict[str, float]:
    """Mean CD2, CD1, F-score@1% of the full dense output against the full truth over a split."""
    model.eval()
    metrics = []
    device = next(model.parameters()).device
    for start in range(0, len(sparse), 16):
        out = model(torch.from_numpy(sparse[start : start + 16]).to(device)).cpu().numpy()
        metrics += [cloud_metrics(p, t) for p, t in zip(out, dense[start : start + 16], strict=True)]
    model.train()
    return {
        "cd2": float(np.mean([m.cd2 for m in metrics])),
        "cd1": float(np.mean([m.cd1 for m in metrics])),
        "fscore": float(np.mean([m.fscore for m in metrics])),
    }


def learning_rate(base: float, step: int, total_steps: int) -> float:
    """Cosine decay from base to MIN_LR_FRACTION·base over the run's steps."""
    f = min(step / max(total_steps, 1), 1.0)
    return base * (MIN_LR_FRACTION + (1.0 - MIN_LR_FRACTION) * 0.5 * (1.0 + math.cos(math.pi * f)))


def run_files(run_name: str) -> tuple[Path, Callable[[str], None]]:
    """A run's checkpoint folder (created) and its `say`: print a line and append it to logs/<run>.log."""
    out_dir = CHECKPOINTS / run_name
    out_dir.mkdir(parents=True, exist_ok=True)
    LOGS.mkdir(parents=True, exist_ok=True)
    log_path = LOGS / f"{run_name}.log"

    def say(text: str) -> None:
        print(text, flush=True)
        with log_path.open("a") as log:
            log.write(text + "\n")

    return out_dir, say


def train(args: argparse.Namespace) -> dict[str, Any]:
    """Run (or resume) one training; returns the final history."""
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    run_name = args.name or args.model
    out_dir, say = run_files(run_name)

    train_data, val_data = load_split("train"), load_split("val")
    usable = np.abs(train_data["dense"]).max(axis=(1, 2)) <= MAX_TRUTH_EXTENT
    seeds = train_data.get("seed", np.arange(len(usable)))
    dropped = [int(seed) for seed in seeds[~usable]]
    sparse = torch.from_numpy(train_data["sparse"][usable][: args.train_limit])
    dense = torch.from_numpy(train_data["dense"][usable][: args.train_limit])
    val_sparse, val_dense = val_data["sparse"][: args.val_limit], val_data["dense"][: args.val_limit]
    variant = args.variant or (run_name if run_name in MODEL_CONFIGS else args.model)
    config = dict(MODEL_CONFIGS[variant])
    recipe = {"model": args.model, "variant": variant, "epochs": args.epochs, "batch_size": args.batch_size,
              "lr": args.lr, "seed": args.seed, "train_limit": args.train_limit, "loss_points": args.loss_points}
    if args.device != "cpu":  # a GPU run's floating point differs from the CPU's: its recipe says where it ran
        recipe["device"] = args.device
    device = torch.device(args.device)
    model = BUILDERS[args.model](**config).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=args.lr)
    history: list[dict[str, float]] = []
    epoch, elapsed, best = 0, 0.0, math.inf
    last = out_dir / "last.pt"
    if last.exists() and not args.fresh:
        state = torch.load(last, weights_only=False, map_location=device)
        if state.get("recipe") != recipe:
            raise SystemExit(f"{last} was written by {state.get('recipe')}, not {recipe}; pass --fresh or another "
                             "--name (resuming would splice two schedules into a run no command reproduces)")
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        epoch, elapsed, history = state["epoch"], state["elapsed_s"], state["history"]
        best = min((h["val_cd2"] for h in history), default=math.inf)
        say(f"resumed {args.model} at epoch {epoch}, {elapsed / 60:.1f} min done")
    else:
        say(f"{args.model}: {parameter_count(model)} parameters, {len(sparse)} train / {len(val_sparse)} val samples "
            f"(left out, truth beyond {MAX_TRUTH_EXTENT} of the cube: seeds {dropped})")
    steps_per_epoch = len(sparse) // args.batch_size
    while epoch < args.epochs:
        gen = torch.Generator().manual_seed(args.seed * 1000 + epoch)  # an epoch's draws depend on it alone
        start, losses = time.perf_counter(), []
        order = torch.randperm(len(sparse), generator=gen)
        for step in range(steps_per_epoch):
            i = step * args.batch_size
            for group in optimizer.param_groups:
                group["lr"] = learning_rate(args.lr, epoch * steps_per_epoch + step, args.epochs * steps_per_epoch)
            x, y = augment(sparse[order[i : i + args.batch_size]], dense[order[i : i + args.batch_size]], gen)
            x, y = x.to(device), y.to(device)
            loss = stage_loss(model.forward_stages(x), y, args.loss_points, gen)  # type: ignore[operator]
            optimizer.zero_grad()
            loss.backward()  # type: ignore[no-untyped-call]
            optimizer.step()
            losses.append(float(loss.detach()))
        elapsed += time.perf_counter() - start
        epoch += 1
        val = validate(model, val_sparse, val_dense)
        history.append({"epoch": epoch, "elapsed_s": elapsed, "train_loss": float(np.mean(losses)),
                        "val_cd2": val["cd2"], "val_cd1": val["cd1"], "val_fscore": val["fscore"]})
        weights = {k: v.cpu() for k, v in model.state_dict().items()}
        state = {"model": weights, "model_config": config, "epoch": epoch, "seed": args.seed, "recipe": recipe,
                 "metrics": {f"val_{k}": v for k, v in val.items()}, "optimizer": optimizer.state_dict(),
                 "elapsed_s": elapsed, "history": history, "export": export_overrides(),
                 "data": {"train": len(sparse), "val": len(val_sparse), "generator": "training.pointcloud_data",
                          "left_out_seeds": dropped}}
        torch.save(state, out_dir / "last.partial.pt")
        (out_dir / "last.partial.pt").replace(last)
        if val["cd2"] < best:
            best = val["cd2"]
            torch.save({k: v for k, v in state.items() if k != "optimizer"}, out_dir / "best.pt")
        say(f"epoch {epoch} {elapsed / 60:.1f} min loss {np.mean(losses) * 1e3:.3f}e-3 "
            f"val CD2 {val['cd2'] * 1e3:.3f}e-3 CD1 {val['cd1'] * 1e2:.3f}e-2 "
            f"F {val['fscore']:.3f} lr {optimizer.param_groups[0]['lr']:.2e}")
    (out_dir / "history.json").write_text(json.dumps(history, indent=1))
    say(f"done {args.model}: {epoch} epochs, {elapsed / 60:.1f} min, best val CD2 {best * 1e3:.3f}e-3")
    return {"history": history, "best_val_cd2": best}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    parser = argparse.ArgumentParser(description="train a point-cloud completion model")
    parser.add_argument("--model", choices=sorted(BUILDERS), required=True)
    parser.add_argument("--name", default=None, help="the run's name (checkpoints, log); a MODEL_CONFIGS key picks "
                        "that variant's sizes")
    parser.add_argument("--variant", default=None, help="a MODEL_CONFIGS variant for a run named otherwise")
    parser.add_argument("--epochs", type=int, required=True, help="the budget: the LR schedule spans its steps")
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--loss-points", type=int, default=2048)
    parser.add_argument("--train-limit", type=int, default=None)
    parser.add_argument("--val-limit", type=int, default=100)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu", help="torch device, e.g. cuda (the shipped runs are cpu)")
    parser.add_argument("--fresh", action="store_true", help="ignore an existing last.pt")
    return parser.parse_args(argv)


if __name__ == "__main__":
    train(parse_args())
