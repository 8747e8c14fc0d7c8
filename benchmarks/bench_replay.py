"""Replay speed of a recorded 10-line simulated survey, and the run log's write and read throughput.

Prints: the run log's append rate for the survey's own record mix (GPR traces, poses, line events)
and for small IMU records (records/s, MB/s, fsync once per second of receive time as in the daemon);
the reader's rate; and replay speed as × real time = survey duration / `replay_run` wall time
(median of 3; it includes writing the PLYs, PNGs and JSON).
Run: `.venv/bin/python -m benchmarks.bench_replay`.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.machine import machine_description
from gprbot.apps.replay import load_run, record_simulated_survey, replay_run, survey_messages
from gprbot.config import load_config
from gprbot.messages import ImuSample
from gprbot.runlog import RunLogWriter
from gprbot.runlog_reader import RunLogReader
from gprbot.sim.scene import load_scene


def write_rate(messages: list[tuple[float, Any]], root: Path, repeats: int = 3) -> tuple[float, float]:
    """Median (records/s, MB/s) of appending `messages` to a fresh run log."""
    rates = []
    for k in range(repeats):
        writer = RunLogWriter(root / f"w{k}", {"created": 0.0})
        start = time.perf_counter()
        for t, message in messages:
            writer.append(message, t)
        writer.close({})
        seconds = time.perf_counter() - start
        rates.append((len(messages) / seconds, writer.bytes_written / seconds / 1e6))
    return statistics.median(r[0] for r in rates), statistics.median(r[1] for r in rates)


def main() -> None:
    """Measure and print."""
    print(machine_description())
    cfg = load_config()  # the default survey: 10 lines of 2 m at 0.1 m/s, 20 traces/s
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        sim = record_simulated_survey(cfg, load_scene("paper_slab"), root / "run")
        messages = survey_messages(sim)
        log_bytes = sum(p.stat().st_size for p in (root / "run").glob("log-*.msgpack"))
        print(f"survey: {cfg.survey.lines} lines, {sim.plan.duration_s:.0f} s, {len(sim.traces)} traces, "
              f"{len(messages)} records, log {log_bytes / 1e6:.1f} MB")

        records_s, mb_s = write_rate(messages, root)
        print(f"write, survey mix (traces+poses+events): {records_s:,.0f} records/s, {mb_s:.0f} MB/s")
        imu = [(0.0025 * k, ImuSample(0.0025 * k, np.zeros(3), np.array([0.0, 0.0, 9.81]))) for k in range(100_000)]
        records_s, mb_s = write_rate(imu, root / "imu")
        print(f"write, IMU records: {records_s:,.0f} records/s, {mb_s:.1f} MB/s (the D435i sends 650/s)")

        start = time.perf_counter()
        count = sum(1 for _ in RunLogReader(root / "run"))
        seconds = time.perf_counter() - start
        print(f"read + decode: {count / seconds:,.0f} records/s, {log_bytes / seconds / 1e6:.0f} MB/s")
        start = time.perf_counter()
        load_run(root / "run")
        print(f"load_run (read, split, windows): {time.perf_counter() - start:.2f} s")

        walls = []
        for k in range(3):
            start = time.perf_counter()
            replay_run(root / "run", root / f"out{k}")
            walls.append(time.perf_counter() - start)
        wall = statistics.median(walls)
        print(f"replay_run: median {wall:.1f} s (runs {', '.join(f'{w:.1f}' for w in walls)}) → "
              f"{sim.plan.duration_s / wall:.1f}× real time")
        same = all((root / f"out{k}" / "dense.ply").read_bytes() == (root / "out0" / "dense.ply").read_bytes()
                   for k in range(3))
        print(f"dense.ply identical over the 3 replays: {same}")


if __name__ == "__main__":
    main()
