"""Train MigrationNet on the cached tiles (training.migration_data) with BCE + Dice, on one CPU thread.

    python -m training.train_migrationnet --epochs 3 --seed 0    # resumes from the last checkpoint
    python -m training.train_migrationnet --init training/checkpoints/migrationnet_stage1.pt \
        --name migrationnet_ft --epochs 2 --lr 1e-3 --seed 1     # second cycle from stage 1's weights
    python -m training.train_migrationnet --calibrate training/checkpoints/migrationnet_ft_best.pt
    python tools/export_onnx.py migrationnet --checkpoint training/checkpoints/migrationnet_ft_best.pt \
        --out models/migrationnet.onnx

The shipped model's full recipe is in its card (models/migrationnet.json, "reproduce").

A checkpoint is written after every epoch (…_last.pt, with optimiser and scheduler for --resume) and
whenever the validation IoU improves (…_best.pt); progress goes to stdout and training/logs/.

The budget is epochs, with fixed seeds: the OneCycle schedule spans exactly --epochs × the steps of
an epoch, so the same command gives the same run on any machine (one thread); wall-clock time is only
reported (epoch_s). A run's log (training/logs/NAME.jsonl) opens with a {"run": ...} line naming the
options that define it, and --resume refuses a checkpoint written with other ones (that would mix two
schedules into a run no command reproduces).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy import ndimage

from gprbot.progress import track
from training.migration_data import CACHE_VERSION, LINES_PER_SCENE, VELOCITY_JITTER, build_split, load_split
from training.migrationnet import MigrationNet, bce_dice_loss, build_migrationnet

ROOT = Path(__file__).resolve().parent
CHECKPOINTS = ROOT / "checkpoints"
LOGS = ROOT / "logs"


def iou_counts(probabilities: torch.Tensor, target: torch.Tensor) -> tuple[float, float, float]:
    """True positives, false positives, false negatives of the mask at 0.5."""
    pred = probabilities >= 0.5
    truth = target >= 0.5
    return (float((pred & truth).sum()), float((pred & ~truth).sum()), float((~pred & truth).sum()))


def evaluate(net: MigrationNet, x: np.ndarray, y: np.ndarray, batch: int = 32) -> dict[str, float]:
    """Pixel IoU, precision, recall and mean loss over a split."""
    net.eval()
    tp = fp = fn = 0.0
    losses = []
    with torch.no_grad():
        for i in range(0, len(x), batch):
            xb = torch.from_numpy(x[i:i + batch].astype(np.float32))
            yb = torch.from_numpy(y[i:i + batch].astype(np.float32))
            logits = net(xb)
            losses.append(float(bce_dice_loss(logits, yb)) * len(xb))
            a, b, c = iou_counts(torch.sigmoid(logits), yb)
            tp, fp, fn = tp + a, fp + b, fn + c
    net.train()
    return {"loss": sum(losses) / len(x), "iou": tp / max(tp + fp + fn, 1.0),
            "precision": tp / max(tp + fp, 1.0), "recall": tp / max(tp + fn, 1.0)}


def augment(xb: torch.Tensor, yb: torch.Tensor, gen: torch.Generator,
            layers: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Mirror along track (half the batch), scale amplitudes by 0.7–1.4 (gain differences), add layers.

    With probability `layers` a tile also gets one to three dipping, gently curved layer echoes that are
    not pipes (geology, screeds, slab interfaces: what the random scenes lack and real lines have).
    """
    flip = torch.rand(len(xb), generator=gen) < 0.5
    xb = torch.where(flip[:, None, None, None], xb.flip(-1), xb)
    yb = torch.where(flip[:, None, None, None], yb.flip(-1), yb)
    scale = torch.exp(torch.empty(len(xb), 1, 1, 1).uniform_(math.log(0.7), math.log(1.4), generator=gen))
    xb = xb * scale
    if layers > 0.0:
        xb = xb + layer_echoes(len(xb), xb.shape[-2], xb.shape[-1], gen, layers)
    return xb, yb


def train_step(net: MigrationNet, optimiser: torch.optim.Optimizer, scheduler: torch.optim.lr_scheduler.LRScheduler,
               xb: torch.Tensor, yb: torch.Tensor, gen: torch.Generator, layers: float) -> float:
    """One augmented BCE + Dice step on a batch (schedule advanced); returns the batch's loss."""
    xb, yb = augment(xb, yb, gen, layers)
    loss = bce_dice_loss(net(xb), yb)
    optimiser.zero_grad()
    loss.backward()
    optimiser.step()
    scheduler.step()
    return float(loss.item())


def layer_echoes(n: int, rows: int, cols: int, gen: torch.Generator, probability: float) -> torch.Tensor:
    """(n, 1, rows, cols) of zero or up to three layer echoes: a Ricker across depth along a dipping curve."""
    out = torch.zeros(n, 1, rows, cols)
    z = torch.arange(rows, dtype=torch.float32)[:, None]
    x = torch.linspace(-1.0, 1.0, cols)[None, :]
    for i in range(n):
        if float(torch.rand(1, generator=gen)) >= probability:
            continue
        for _ in range(int(torch.randint(1, 4, (1,), generator=gen))):
            a, dip, bend, width, amp = (torch.rand(5, generator=gen) * torch.tensor([rows, 0.6, 0.16, 6.0, 2.5])
                                        + torch.tensor([0.0, -0.3, -0.08, 2.0, 0.3]))
            centre = a + rows * (dip * x + bend * x**2)
            u = ((z - centre) / width) ** 2
            sign = 1.0 if float(torch.rand(1, generator=gen)) < 0.5 else -1.0
            out[i, 0] += sign * amp * (1.0 - 2.0 * u) * torch.exp(-u)
    return out


def save(path: Path, model: torch.nn.Module, config: dict[str, Any], epoch: int, seed: int,
         metrics: dict[str, Any], extra: dict[str, Any]) -> None:
    """A checkpoint in the shared format (model, model_config, epoch, seed, metrics, data) plus extras."""
    tmp = path.with_suffix(".tmp")
    torch.save({"model": model.state_dict(), "model_config": config, "epoch": epoch, "seed": seed,
                "metrics": metrics, "data": data_description(), **extra}, tmp)
    tmp.replace(path)


def data_description() -> str:
    """What the model was trained on, for the model card."""
    return (f"training.random_scenes split 'train' (1378 scenes, seeds 0-1377), {LINES_PER_SCENE} random lines per "
            f"scene, one 128x128 depth tile per line (training.migration_data, cache v{CACHE_VERSION}: "
            f"calibrated simulator, domain-randomised train/val lines); velocity jitter "
            f"{VELOCITY_JITTER:.0%}; validation: split 'val' (100 scenes, seeds 100000-100099)")


RECIPE = ("epochs", "batch", "lr", "width", "seed", "threads", "limit", "layers", "init")


def recipe(args: argparse.Namespace) -> dict[str, Any]:
    """The options that define a run (its budget, schedule, data and start), as its log and checkpoint record them."""
    return {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items() if k in RECIPE}


def train(args: argparse.Namespace) -> dict[str, Any]:
    """Train (or resume) and return the best validation metrics."""
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    gen = torch.Generator().manual_seed(args.seed)
    x_train, y_train = load_split(build_split("train", limit=args.limit))
    x_val, y_val = load_split(build_split("val", limit=args.limit))
    config = {"width": args.width}
    model = build_migrationnet(**config)
    net: MigrationNet = model.net  # type: ignore[assignment]
    optimiser = torch.optim.AdamW(net.parameters(), lr=args.lr, weight_decay=1e-4)
    steps_per_epoch = math.ceil(len(x_train) / args.batch)
    scheduler = torch.optim.lr_scheduler.OneCycleLR(
        optimiser, max_lr=args.lr, total_steps=args.epochs * steps_per_epoch, pct_start=0.1)
    CHECKPOINTS.mkdir(parents=True, exist_ok=True)
    LOGS.mkdir(parents=True, exist_ok=True)
    last, best_path = CHECKPOINTS / f"{args.name}_last.pt", CHECKPOINTS / f"{args.name}_best.pt"
    start_epoch, best, history = 0, {"iou": -1.0}, []
    if args.init is not None:  # fine-tune: weights only, fresh optimiser and schedule
        model.load_state_dict(torch.load(args.init, weights_only=False)["model"])
        print(f"initialised from {args.init}", flush=True)
    if args.resume and last.exists():
        state = torch.load(last, weights_only=False)
        if state.get("recipe", recipe(args)) != recipe(args):
            raise SystemExit(f"{last} was written by a run with {state['recipe']}, not {recipe(args)}: resume it "
                             "with the same options, or start afresh with --no-resume or another --name")
        model.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        scheduler.load_state_dict(state["scheduler"])
        gen.set_state(state["generator"])
        start_epoch, best, history = state["epoch"], state["best"], state["history"]
        print(f"resumed after epoch {start_epoch}", flush=True)
    log = (LOGS / f"{args.name}.jsonl").open("a")
    if start_epoch == 0:
        log.write(json.dumps({"run": recipe(args), "name": args.name}) + "\n")
    for epoch in range(start_epoch, args.epochs):
        t0 = time.perf_counter()
        order = torch.randperm(len(x_train), generator=gen).numpy()
        running = 0.0
        for step in track(range(steps_per_epoch), f"epoch {epoch + 1}/{args.epochs}", unit="step"):
            idx = np.sort(order[step * args.batch:(step + 1) * args.batch])
            xb = torch.from_numpy(x_train[idx].astype(np.float32))
            yb = torch.from_numpy(y_train[idx].astype(np.float32))
            running += train_step(net, optimiser, scheduler, xb, yb, gen, args.layers)
            if (step + 1) % 50 == 0:
                print(f"epoch {epoch + 1} step {step + 1}/{steps_per_epoch} loss {running / (step + 1):.4f} "
                      f"{time.perf_counter() - t0:.0f} s", flush=True)
        metrics = {"epoch": epoch + 1, "train_loss": running / steps_per_epoch,
                   **{f"val_{k}": v for k, v in evaluate(net, x_val, y_val).items()},
                   "epoch_s": time.perf_counter() - t0}
        history.append(metrics)
        log.write(json.dumps(metrics) + "\n")
        log.flush()
        print(json.dumps(metrics), flush=True)
        if metrics["val_iou"] > best["iou"]:
            best = {"iou": metrics["val_iou"], "epoch": epoch + 1}
            save(best_path, model, config, epoch + 1, args.seed, {"val": metrics, "history": history}, {})
        if args.keep_epochs:  # each epoch kept, for model selection on the FDTD dev half (training.select_fdtd)
            save(CHECKPOINTS / f"{args.name}_e{epoch + 1}.pt", model, config, epoch + 1, args.seed,
                 {"val": metrics, "history": history}, {})
        save(last, model, config, epoch + 1, args.seed, {"val": metrics, "history": history},
             {"optimiser": optimiser.state_dict(), "scheduler": scheduler.state_dict(),
              "generator": gen.get_state(), "best": best, "history": history, "recipe": recipe(args)})
    log.close()
    return best


def calibrate_threshold(checkpoint: Path, limit: int | None = None) -> dict[str, float]:
    """Pick the probability threshold with the best validation IoU and store it in the checkpoint's metrics."""
    state = torch.load(checkpoint, weights_only=False)
    model = build_migrationnet(**state["model_config"])
    model.load_state_dict(state["model"])
    net: MigrationNet = model.net  # type: ignore[assignment]
    net.eval()
    x_val, y_val = load_split(build_split("val", limit=limit))
    with torch.no_grad():
        probabilities = torch.cat([torch.sigmoid(net(torch.from_numpy(x_val[i:i + 32].astype(np.float32))))
                                   for i in range(0, len(x_val), 32)])
    truth = torch.from_numpy(y_val.astype(bool))
    sweep = {}
    for threshold in np.arange(0.2, 0.75, 0.05):
        pred = probabilities >= float(threshold)
        tp, fp, fn = float((pred & truth).sum()), float((pred & ~truth).sum()), float((~pred & truth).sum())
        sweep[round(float(threshold), 2)] = tp / max(tp + fp + fn, 1.0)
    best = max(sweep, key=lambda t: sweep[t])
    state["metrics"]["threshold"] = best
    state["metrics"]["val_iou_at_threshold"] = sweep[best]
    state["metrics"]["threshold_sweep"] = sweep
    peaks = true_blob_peaks(probabilities[:, 0].numpy(), truth[:, 0].numpy(), best)
    state["metrics"]["min_peak"] = min_peak_keeping(peaks)
    torch.save(state, checkpoint)
    print(f"threshold {best} (val IoU {sweep[best]:.4f}); sweep {sweep}; min peak {state['metrics']['min_peak']} "
          f"(keeps {np.mean(peaks >= state['metrics']['min_peak']):.4f} of {len(peaks)} true blobs)", flush=True)
    return sweep


def true_blob_peaks(probability: np.ndarray, truth: np.ndarray, threshold: float) -> np.ndarray:
    """Peak probability of every blob (probability ≥ threshold) that overlaps a true pipe, over (n, rows, cols)."""
    peaks = []
    for p, t in zip(probability, truth, strict=True):
        labels, n = ndimage.label(p >= threshold)
        for index in range(1, n + 1):
            blob = labels == index
            if (blob & t).any():
                peaks.append(float(p[blob].max()))
    return np.asarray(peaks)


def min_peak_keeping(peaks: np.ndarray, step: float = 0.05) -> float:
    """The highest multiple of `step` at or under every true blob's peak (0 when there are none).

    Every true blob of the validation split is kept; what peaks lower is less sure than the network ever was of
    a real pipe in its own domain (on real field lines: clutter at 0.54-0.68; FDTD dev pipes: 0.90-1.00).
    """
    if not len(peaks):
        return 0.0
    return round(math.floor(float(peaks.min()) / step + 1e-9) * step, 2)


def main() -> None:
    """CLI."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=6)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--lr", type=float, default=3e-3)
    parser.add_argument("--width", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--limit", type=int, default=None, help="only the first N scenes of each split")
    parser.add_argument("--name", default="migrationnet")
    parser.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True)
    parser.add_argument("--layers", type=float, default=0.0,
                        help="probability of adding non-pipe layer echoes to a training tile (augment)")
    parser.add_argument("--keep-epochs", action="store_true", help="also keep every epoch's weights (…_eN.pt)")
    parser.add_argument("--init", type=Path, default=None, help="start from this checkpoint's weights")
    parser.add_argument("--calibrate", type=Path, default=None,
                        help="only pick the mask threshold on the validation split and store it in this checkpoint")
    args = parser.parse_args()
    if args.calibrate is not None:
        calibrate_threshold(args.calibrate, args.limit)
        return
    print(train(args), flush=True)


if __name__ == "__main__":
    main()
