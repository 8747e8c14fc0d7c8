"""Run gprMax for every scene without a finished output (resumable, cached by the .in hash) and export each.

    python -m validation.fdtd.run [--jobs 1] [--only NAME] [--list] [--convert-only]

Runs under the separate venv that has gprMax (see validation/README.md). Each scene runs in
work/<name>/<sha256[:16]>/, one HDF5 file per trace; a run cut short resumes at its first missing or
unreadable trace (`-i`). Finished B-scans are merged into bscan.npz there and exported to data/.
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from validation.fdtd.convert import WORK, export, is_exported
from validation.fdtd.gprmax_input import describe, in_sha256, input_text, layout
from validation.fdtd.scenes import Scene, all_scenes

COSTS = Path(__file__).resolve().parent / "costs.csv"
POLL_S = 20.0


def queue(scenes: list[Scene]) -> list[Scene]:
    """Cheap scenes first, dev and test interleaved, so a partial batch fills both halves evenly; the training
    batch after them, then the holdout batch."""
    by_half = {h: sorted((s for s in scenes if s.half == h), key=lambda s: layout(s).estimate_s(s.traces))
               for h in ("dev", "test", "train", "holdout")}
    out: list[Scene] = []
    for i in range(max(len(by_half["dev"]), len(by_half["test"]))):
        out += [by_half[h][i] for h in ("dev", "test") if i < len(by_half[h])]
    return out + by_half["train"] + by_half["holdout"]


def run_dir(scene: Scene) -> Path:
    """The cache folder of a scene's current input text."""
    return WORK / scene.name / in_sha256(input_text(scene))[:16]


def _trace_ok(path: Path) -> bool:
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return bool(len(f["rxs/rx1/Ez"]) == int(f.attrs["Iterations"]))
    except (OSError, KeyError, ValueError):
        return False


def first_missing(scene: Scene, folder: Path) -> int:
    """1-based number of the first trace without a readable output file (traces + 1 when all are there)."""
    for k in range(1, scene.traces + 1):
        if not _trace_ok(folder / f"{scene.name}{k}.h5"):
            return k
    return scene.traces + 1


def merge(scene: Scene, folder: Path) -> tuple[np.ndarray, float, str]:
    """Stack the per-trace Ez records into (traces, iterations); the time step and gprMax version."""
    import h5py

    traces, dt, version = [], 0.0, ""
    for k in range(1, scene.traces + 1):
        with h5py.File(folder / f"{scene.name}{k}.h5", "r") as f:
            traces.append(np.asarray(f["rxs/rx1/Ez"], dtype=np.float64))
            dt, version = float(f.attrs["dt"]), str(f.attrs["gprMax"])
    return np.stack(traces), dt, version


def simulate(scene: Scene, log: bool = True) -> float:
    """Run (or resume) gprMax for a scene; seconds spent now. Leaves bscan.npz in the run folder."""
    folder = run_dir(scene)
    folder.mkdir(parents=True, exist_ok=True)
    infile = folder / f"{scene.name}.in"
    infile.write_text(input_text(scene))
    start = first_missing(scene, folder)
    for k in range(start, scene.traces + 1):  # a partial file from an interrupted run is redone
        (folder / f"{scene.name}{k}.h5").unlink(missing_ok=True)
    began = time.monotonic()
    if start <= scene.traces:
        env = dict(os.environ, OMP_NUM_THREADS="1")
        cmd = ["nice", "-n", "19", sys.executable, "-m", "gprMax", infile.name, "-n", str(scene.traces - start + 1),
               "-i", str(start), "--geometry-fixed", "--hide-progress-bars"]
        with open(folder / "gprmax.log", "a") as out:
            proc = subprocess.Popen(cmd, cwd=folder, env=env, stdout=out, stderr=subprocess.STDOUT)
            while True:
                try:
                    proc.wait(timeout=POLL_S * 3)
                    break
                except subprocess.TimeoutExpired:
                    done = len(list(folder.glob(f"{scene.name}*.h5"))) - 1
                    spent = time.monotonic() - began
                    rate = spent / max(1, done - start + 1)
                    if log:
                        print(f"  {scene.name}: {max(done, 0)}/{scene.traces} traces, {spent:.0f} s, "
                              f"~{rate * (scene.traces - done):.0f} s left", flush=True)
        single = folder / f"{scene.name}.h5"  # gprMax drops the model number when it runs one model
        if start == scene.traces and single.exists():
            single.replace(folder / f"{scene.name}{start}.h5")
        if proc.returncode != 0 or first_missing(scene, folder) <= scene.traces:
            raise RuntimeError(f"gprMax failed on {scene.name} (rc {proc.returncode}); see {folder / 'gprmax.log'}")
    ez, dt, version = merge(scene, folder)
    np.savez_compressed(folder / "bscan.npz", ez=ez, dt=dt, version=version)
    return time.monotonic() - began


def finish(scene: Scene) -> float:
    """Simulate if needed and export; the seconds gprMax ran this time (0 when cached)."""
    folder = run_dir(scene)
    spent = 0.0
    if not (folder / "bscan.npz").exists():
        spent = simulate(scene)
    with np.load(folder / "bscan.npz") as z:
        export(scene, z["ez"], float(z["dt"]), str(z["version"]))
    return spent


def measured_s(scene: Scene) -> float | None:
    """Seconds one core spent on a finished scene: the median gap between trace files' times × traces."""
    folder = run_dir(scene)
    times = sorted(p.stat().st_mtime for p in folder.glob(f"{scene.name}*.h5"))
    if len(times) < 3 or not (folder / "bscan.npz").exists():
        return None
    return float(np.median(np.diff(times))) * scene.traces


def write_costs(scenes: list[Scene]) -> None:
    """costs.csv: the estimate and the measured cost of every finished scene (robust to resumed runs).

    A scene whose runs are not in this checkout's work/ (work/ is not committed) keeps the row it has.
    """
    kept: dict[str, dict[str, object]] = {}
    if COSTS.exists():
        with open(COSTS) as f:
            kept = {r["name"]: dict(r) for r in csv.DictReader(f)}
    rows = []
    for s in sorted(scenes, key=lambda s: s.name):
        seconds = measured_s(s)
        if seconds is not None:
            lay = layout(s)
            rows.append({"name": s.name, "half": s.half, "traces": s.traces, "cells": lay.nx * lay.ny,
                         "iterations": lay.iterations, "estimate_s": round(lay.estimate_s(s.traces)),
                         "measured_s": round(seconds, 1)})
        elif s.name in kept:
            rows.append(kept[s.name])
    with open(COSTS, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["name", "half", "traces", "cells", "iterations", "estimate_s",
                                               "measured_s"])
        writer.writeheader()
        writer.writerows(rows)


def table(scenes: list[Scene]) -> str:
    """A markdown table of the scenes: kind, frequency, half, size and the estimated and measured cost."""
    measured = {}
    if COSTS.exists():
        with open(COSTS) as f:
            measured = {r["name"]: r["measured_s"] for r in csv.DictReader(f)}
    rows = ["| name | kind | MHz | half | targets | traces x step | grid | est. s | measured s |",
            "|---|---|---|---|---|---|---|---|---|"]
    for s in scenes:
        lay = layout(s)
        targets = ", ".join([p.fill for p in s.pipes] + ([f"{len(s.rebars)} rebars"] if s.rebars else [])
                            + ([f"bottom {s.slab_bottom_m:g} m/{s.below}"] if s.slab_bottom_m else [])) or "none"
        rows.append(f"| {s.name} | {s.kind} | {s.frequency_mhz:.0f} | {s.half} | {targets} | "
                    f"{s.traces} x {s.step_m * 100:g} cm | {lay.dx_m * 1e3:g} mm | {lay.estimate_s(s.traces):.0f} | "
                    f"{measured.get(s.name, '–')} |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    """Entry point: list, convert, or run the queue."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=1, help="scenes run at once, one core each")
    ap.add_argument("--only", action="append", help="run only this scene (repeatable)")
    ap.add_argument("--list", action="store_true", help="print the queue with cost estimates and stop")
    ap.add_argument("--convert-only", action="store_true", help="re-export finished runs, start no simulation")
    ap.add_argument("--table", action="store_true", help="print the scene table of validation/README.md and stop")
    args = ap.parse_args(argv)
    if args.table:
        write_costs(all_scenes())
        print(table(all_scenes()))
        return 0
    scenes = queue(all_scenes())
    if args.only:
        scenes = [s for s in scenes if s.name in set(args.only)]
    if args.list:
        for s in scenes:
            state = "done" if is_exported(s) else "todo"
            print(f"{state} {s.half:4s} {s.kind:18s} {s.frequency_mhz:7.1f} MHz  {describe(s)}")
        return 0
    todo = [s for s in scenes if not is_exported(s) or args.convert_only]
    if args.convert_only:
        todo = [s for s in todo if (run_dir(s) / "bscan.npz").exists()]
    total = sum(layout(s).estimate_s(s.traces) for s in todo) / max(1, args.jobs)
    print(f"{len(todo)} of {len(scenes)} scenes to do, estimate {total / 60:.0f} min with {args.jobs} job(s)",
          flush=True)
    began, done = time.monotonic(), 0

    def one(s: Scene) -> None:
        nonlocal done
        print(f"start {s.name} ({s.half}): {describe(s)}", flush=True)
        done += 1
        try:
            spent = finish(s)
        except (RuntimeError, OSError, ValueError) as exc:  # one broken scene must not stop the batch
            print(f"FAILED {s.name}: {exc}", flush=True)
            return
        write_costs(scenes)
        elapsed = time.monotonic() - began
        left = sum(layout(t).estimate_s(t.traces) for t in todo[done:]) / max(1, args.jobs)
        print(f"done  {s.name} in {spent:.0f} s  [{done}/{len(todo)}, {elapsed / 60:.1f} min, "
              f"ETA ~{left / 60:.0f} min]", flush=True)

    if args.jobs <= 1:
        for s in todo:
            one(s)
    else:
        with ThreadPoolExecutor(args.jobs) as pool:
            list(pool.map(one, todo))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
