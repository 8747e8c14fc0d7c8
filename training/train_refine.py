"""Train the FitRefiner on training.refine_data, on a budget of epochs, with resume.

    python -m training.train_refine --epochs 12 --seed 0 --name fit_refiner_s0

The budget is epochs (the cosine learning-rate schedule runs over its steps), so a run's result does
not depend on how fast the machine is; the wall clock is only reported. Every epoch writes
training/checkpoints/<name>/last.pt (resume: re-run the same command) and, when the validation loss
improves, best.pt. Each step draws FIT_POINTS of a sample's fitted-rod points and QUERY_POINTS of its
candidates. Loss: the candidates' binary cross-entropy (inside a true pipe or not) + CD2 (×10³, the
tables' unit) between the moved candidates that truly lie inside a pipe and a LOSS_POINTS subset of the
truth, weighted by REFINE_WEIGHT.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch.nn import functional as F  # noqa: N812 (the usual name)

from gprbot.infer.refine import MAX_PIPES, accepted
from training.chamfer import chamfer_sq_terms
from training.refine_data import build_split
from training.refine_model import FitRefiner
from training.train_completion import MAX_TRUTH_EXTENT, learning_rate, random_subset, run_files

REFINE_WEIGHT = 1.0
FIT_POINTS = 1024  # as gprbot.infer.refine feeds them
QUERY_POINTS = 2048  # per step, of the sample's 4096 candidates (the runtime judges 16384)
LOSS_POINTS = 2048
FAR = 10.0  # candidates outside the truth are moved this far so that no truth point picks them as its nearest
ARRAYS = ("sparse", "fit", "fit_pipe", "query", "query_pipe", "beyond", "inside", "dense")


def onehot(pipe: torch.Tensor) -> torch.Tensor:
    """Pipe indices (B, N) → one-hot (B, N, MAX_PIPES); indices ≥ MAX_PIPES → rows of zeros."""
    return F.one_hot(pipe.long().clamp(max=MAX_PIPES), MAX_PIPES + 1)[..., :MAX_PIPES].float()


def refine_loss(moved: torch.Tensor, keep: torch.Tensor, truth: torch.Tensor, both_ways: bool = True) -> torch.Tensor:
    """Mean over samples with a kept point of CD2 (×10³) between the kept moved points and the truth.

    both_ways=False keeps only the points → truth term: each point is pulled into the pipe it lies by, and
    no point is pulled away to cover truth that no candidate reaches (the `into-truth` offset loss).
    """
    shifted = moved + FAR * (~keep).unsqueeze(-1).float()
    to_truth, to_pred = chamfer_sq_terms(shifted, truth)
    kept = keep.float()
    count = kept.sum(dim=1)
    cd2 = (to_truth * kept).sum(dim=1) / count.clamp(min=1.0) + (to_pred.mean(dim=1) if both_ways else 0.0)
    valid = count > 0
    return 1e3 * cd2[valid].mean() if bool(valid.any()) else torch.zeros(())


def augment(batch: dict[str, torch.Tensor], gen: torch.Generator) -> dict[str, torch.Tensor]:
    """Mirror x and/or y per sample (lines stay along x, depth stays down)."""
    b = batch["sparse"].shape[0]
    signs = torch.ones(b, 1, 3)
    signs[:, 0, :2] = torch.where(torch.rand(b, 2, generator=gen) < 0.5, -1.0, 1.0)
    return {**batch, **{k: batch[k] * signs for k in ("sparse", "fit", "query", "dense")}}


def random_rows(b: int, m: int, n: int, gen: torch.Generator) -> torch.Tensor:
    """n random row indices out of m for each of b samples (B, n)."""
    return torch.stack([torch.randperm(m, generator=gen)[:n] for _ in range(b)])


def thin(batch: dict[str, torch.Tensor], gen: torch.Generator) -> dict[str, torch.Tensor]:
    """FIT_POINTS of each sample's fitted-rod points and QUERY_POINTS of its candidates, drawn at random."""
    b = batch["fit"].shape[0]
    fit_rows = random_rows(b, batch["fit"].shape[1], FIT_POINTS, gen)
    query_rows = random_rows(b, batch["query"].shape[1], QUERY_POINTS, gen)

    def take(key: str, rows: torch.Tensor) -> torch.Tensor:
        x = batch[key]
        return torch.gather(x, 1, rows.unsqueeze(-1).expand(-1, -1, 3)) if x.dim() == 3 else torch.gather(x, 1, rows)

    return {**batch, "fit": take("fit", fit_rows), "fit_pipe": take("fit_pipe", fit_rows),
            **{k: take(k, query_rows) for k in ("query", "query_pipe", "beyond", "inside")}}


def predict(model: FitRefiner, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Logits (B, Q) and moved candidates (B, Q, 3) of a batch."""
    return model(batch["sparse"], batch["fit"], onehot(batch["fit_pipe"]), batch["query"], onehot(batch["query_pipe"]),
                 batch["beyond"].unsqueeze(-1))  # type: ignore[no-any-return]


def accept_loss(logits: torch.Tensor, inside: torch.Tensor, outside_weight: float = 1.0) -> torch.Tensor:
    """Binary cross-entropy of the candidates, a candidate outside every true pipe weighted outside_weight."""
    weight = torch.where(inside > 0.5, 1.0, outside_weight)
    return F.binary_cross_entropy_with_logits(logits, inside, weight=weight)


def step_losses(model: FitRefiner, batch: dict[str, torch.Tensor], gen: torch.Generator,
                outside_weight: float = 1.0, offset_loss: str = "chamfer") -> tuple[torch.Tensor, ...]:
    """Candidate classification and refinement losses of one batch."""
    logits, moved = predict(model, batch)
    accept = accept_loss(logits, batch["inside"], outside_weight)
    truth = random_subset(batch["dense"], LOSS_POINTS, gen)
    return accept, refine_loss(moved, batch["inside"] > 0.5, truth, both_ways=offset_loss == "chamfer")


def tensors(arrays: dict[str, NDArray[Any]], rows: NDArray[np.intp]) -> dict[str, torch.Tensor]:
    """The model's arrays of some samples as tensors."""
    return {k: torch.from_numpy(np.ascontiguousarray(arrays[k][rows])) for k in ARRAYS}


@torch.no_grad()
def validate(model: FitRefiner, arrays: dict[str, NDArray[Any]]) -> dict[str, float]:
    """Val losses, candidate accuracy, and per-sample CD2 (×10³): the fit's points, the accepted moved ones, the rule's.

    The comparison is in the unit cube against a fixed 4096-point subset of each truth; the fit is its
    FIT_POINTS rod points, ours as many drawn from the accepted candidates (the run-time rule,
    gprbot.infer.refine.accepted); the rule is the same accepted candidates unmoved, so median_cd2 against
    rule_median_cd2 is the offsets' own share (the `extended` completion accepts every candidate).
    """
    model.eval()
    gen = torch.Generator().manual_seed(0)
    accept, refine, correct, total, fit_cd2, ours_cd2, rule_cd2 = [], [], 0, 0, [], [], []
    for start in range(0, len(arrays["seed"]), 16):
        batch = thin(tensors(arrays, np.arange(start, min(start + 16, len(arrays["seed"])))), gen)
        truth = random_subset(batch["dense"], 2 * LOSS_POINTS, gen)
        logits, moved = predict(model, batch)
        accept.append(float(F.binary_cross_entropy_with_logits(logits, batch["inside"])))
        refine.append(float(refine_loss(moved, batch["inside"] > 0.5, truth)))
        correct += int(((logits > 0) == (batch["inside"] > 0.5)).sum())
        total += logits.numel()
        probability, pipe, beyond = torch.sigmoid(logits).numpy(), batch["query_pipe"].numpy(), batch["beyond"].numpy()
        for i in range(len(moved)):
            one = slice(i, i + 1)
            every = torch.ones(1, FIT_POINTS, dtype=torch.bool)
            fit_cd2.append(float(refine_loss(batch["fit"][one], every, truth[one])))
            points, _ = accepted(probability[i], pipe[i], beyond[i], int(pipe[i].max()) + 1)  # the run-time rule
            # as many points as the fit's, so both clouds sit on the same sampling floor
            rows = torch.multinomial(torch.from_numpy(points).float(), FIT_POINTS, replacement=True, generator=gen)
            ours = moved[i][rows].unsqueeze(0)
            ours_cd2.append(float(refine_loss(ours, every, truth[one])))
            rule_cd2.append(float(refine_loss(batch["query"][i][rows].unsqueeze(0), every, truth[one])))
    model.train()
    return {"accept": float(np.mean(accept)), "refine": float(np.mean(refine)), "accuracy": correct / max(total, 1),
            "fit_median_cd2": float(np.median(fit_cd2)), "median_cd2": float(np.median(ours_cd2)),
            "fit_mean_cd2": float(np.mean(fit_cd2)), "mean_cd2": float(np.mean(ours_cd2)),
            "rule_median_cd2": float(np.median(rule_cd2)), "rule_mean_cd2": float(np.mean(rule_cd2))}


def usable(arrays: dict[str, NDArray[Any]]) -> NDArray[np.bool_]:
    """Samples whose truth fits the cube (see MAX_TRUTH_EXTENT)."""
    return np.asarray(np.abs(arrays["dense"]).max(axis=(1, 2)) <= MAX_TRUTH_EXTENT)


def train(args: argparse.Namespace) -> dict[str, Any]:
    """Run (or resume) one training; returns the history."""
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    out_dir, say = run_files(args.name)

    train_all = build_split("train", args.train_limit)
    val_all = build_split("val", args.val_limit)
    train_rows = np.flatnonzero(usable(train_all))
    val = {k: x[usable(val_all)] for k, x in val_all.items() if k != "skipped"}
    config = {"local": args.local, "point": args.point, "global_dim": args.global_dim, "hidden": args.hidden}
    model = FitRefiner(**config)
    optimizer = torch.optim.Adam(model.parameters(), lr=args.lr)
    steps_per_epoch = len(train_rows) // args.batch_size
    total_steps = args.epochs * steps_per_epoch
    history: list[dict[str, float]] = []
    epoch, elapsed, best = 0, 0.0, math.inf
    last = out_dir / "last.pt"
    if last.exists() and not args.fresh:
        state = torch.load(last, weights_only=False)
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        epoch, elapsed, history = state["epoch"], state["elapsed_s"], state["history"]
        best = min((h["val_loss"] for h in history), default=math.inf)
        say(f"resumed {args.name} at epoch {epoch}")
    else:
        say(f"{args.name}: {sum(p.numel() for p in model.parameters())} parameters, {len(train_rows)} train / "
            f"{len(val['seed'])} val samples, {args.epochs} epochs × {steps_per_epoch} steps, seed {args.seed}")
    while epoch < args.epochs:
        gen = torch.Generator().manual_seed(args.seed * 1000 + epoch)  # an epoch's draws depend on it alone
        start, losses = time.perf_counter(), []
        order = train_rows[torch.randperm(len(train_rows), generator=gen).numpy()]
        for i in range(steps_per_epoch):
            for group in optimizer.param_groups:
                group["lr"] = learning_rate(args.lr, epoch * steps_per_epoch + i, total_steps)
            batch = thin(augment(tensors(train_all, order[i * args.batch_size : (i + 1) * args.batch_size]), gen), gen)
            accept, refine = step_losses(model, batch, gen, args.outside_weight, args.offset_loss)
            loss = accept + REFINE_WEIGHT * refine
            optimizer.zero_grad()
            loss.backward()  # type: ignore[no-untyped-call]
            optimizer.step()
            losses.append((float(accept), float(refine)))
        elapsed += time.perf_counter() - start
        epoch += 1
        v = validate(model, val)
        val_loss = v["accept"] + REFINE_WEIGHT * v["refine"]
        history.append({"epoch": epoch, "elapsed_s": elapsed, "train_accept": float(np.mean([a for a, _ in losses])),
                        "train_refine": float(np.mean([r for _, r in losses])), "val_loss": val_loss,
                        **{f"val_{k}": x for k, x in v.items()}})
        state = {"model": model.state_dict(), "model_config": config, "epoch": epoch, "seed": args.seed,
                 "optimizer": optimizer.state_dict(), "elapsed_s": elapsed, "history": history,
                 "metrics": {f"val_{k}": x for k, x in v.items()}, "budget": {"epochs": args.epochs},
                 "recipe": {"outside_weight": args.outside_weight, "offset_loss": args.offset_loss},
                 "data": {"generator": "training.refine_data", "train": len(train_rows), "val": len(val["seed"])}}
        torch.save(state, out_dir / "last.partial.pt")
        (out_dir / "last.partial.pt").replace(last)
        if val_loss < best:
            best = val_loss
            torch.save({k: x for k, x in state.items() if k != "optimizer"}, out_dir / "best.pt")
        say(f"epoch {epoch} {elapsed / 60:.1f} min accept {history[-1]['train_accept']:.3f} refine "
            f"{history[-1]['train_refine']:.3f} | val accept {v['accept']:.3f} refine {v['refine']:.3f} acc "
            f"{v['accuracy']:.3f} median CD2 {v['median_cd2']:.3f} (fit {v['fit_median_cd2']:.3f}, rule "
            f"{v['rule_median_cd2']:.3f}) mean {v['mean_cd2']:.3f} (fit {v['fit_mean_cd2']:.3f}, rule "
            f"{v['rule_mean_cd2']:.3f})")
    (out_dir / "history.json").write_text(json.dumps(history, indent=1))
    return {"history": history, "best_val_loss": best}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--name", default="fit_refiner")
    parser.add_argument("--epochs", type=int, default=12, help="the budget (the LR schedule spans it)")
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--local", type=int, default=64)
    parser.add_argument("--point", type=int, default=128)
    parser.add_argument("--global-dim", type=int, default=256)
    parser.add_argument("--hidden", type=int, default=128)
    parser.add_argument("--outside-weight", type=float, default=1.0,
                        help="weight of a candidate outside every true pipe in the acceptance loss (1: the shipped "
                             "recipe, whose acceptance learnt to accept every candidate: 92 %% lie inside)")
    parser.add_argument("--offset-loss", choices=("chamfer", "into-truth"), default="chamfer",
                        help="what the offsets learn: chamfer (both ways, the shipped recipe: points are also "
                             "pulled towards truth no candidate covers) or into-truth (each accepted point into its "
                             "pipe only)")
    parser.add_argument("--train-limit", type=int, default=900, help="the first N training seeds (the cache's)")
    parser.add_argument("--val-limit", type=int, default=None)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fresh", action="store_true", help="ignore an existing last.pt")
    return parser.parse_args(argv)


if __name__ == "__main__":
    train(parse_args())
