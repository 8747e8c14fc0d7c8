"""Forward-model throughput: a 10-line survey (one simulate_bscan call per line) per built-in scene.

Prints the median over several runs of the time per survey and the traces per second, for 512 and
1024 samples per trace, and describes the machine. Run: `.venv/bin/python -m benchmarks.bench_forward`.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from benchmarks.machine import machine_description
from gprbot.config import GprConfig
from gprbot.sim.forward import simulate_bscan
from gprbot.sim.scene import builtin_scene_names, load_scene


def survey_lines(lines: int, traces_per_line: int) -> list[np.ndarray]:
    """The default survey's antenna midpoints: lines along x over [0, 2] m, 10 cm apart in y."""
    x = np.linspace(0.0, 2.0, traces_per_line)
    return [np.stack([x, np.full_like(x, 0.1 * i)], axis=1) for i in range(lines)]


def time_survey(scene_name: str, samples: int, lines: list[np.ndarray], repeats: int) -> float:
    """Median seconds to simulate all lines once."""
    scene = load_scene(scene_name)
    gpr = GprConfig(samples=samples)
    durations = []
    for repeat in range(repeats + 1):
        rng = np.random.default_rng(repeat)
        start = time.perf_counter()
        for mid in lines:
            simulate_bscan(scene, mid, gpr, rng)
        if repeat:  # the first run warms caches and imports
            durations.append(time.perf_counter() - start)
    return statistics.median(durations)


def main(argv: list[str] | None = None) -> None:
    """Print the benchmark table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--lines", type=int, default=10)
    parser.add_argument("--traces-per-line", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    lines = survey_lines(args.lines, args.traces_per_line)
    n_traces = args.lines * args.traces_per_line
    print(f"machine: {machine_description()}")
    print(f"survey: {args.lines} lines x {args.traces_per_line} traces, median of {args.repeats} runs")
    print(f"{'scene':<18}{'samples':>8}{'ms/survey':>12}{'traces/s':>12}")
    for samples in (512, 1024):
        for name in builtin_scene_names():
            seconds = time_survey(name, samples, lines, args.repeats)
            print(f"{name:<18}{samples:>8}{seconds * 1e3:>12.1f}{n_traces / seconds:>12.0f}")


if __name__ == "__main__":
    main()
