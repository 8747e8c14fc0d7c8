"""Benchmark: time per B-scan of Kirchhoff and Stolt migration (and a whole interpretation).

Run: .venv/bin/python -m benchmarks.bench_migration  — prints medians and describes the machine.
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from collections.abc import Callable
from functools import partial

import numpy as np

from gprbot.config import GprConfig, InterpretationConfig
from gprbot.gpr.bscan import SyntheticTarget, synthetic_bscan
from gprbot.gpr.interpret import interpret_bscan
from gprbot.gpr.migration import depth_axis, migrate, resample_uniform
from gprbot.gpr.traveltime import velocity_from_eps

GPR = GprConfig()
CFG = InterpretationConfig()
V = velocity_from_eps(6.25)


def _median_seconds(run: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _machine() -> str:
    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
            f"numpy {np.__version__}, {platform.system()} {platform.release()}")


def main() -> None:
    """Print median wall times per B-scan (512 samples, 1 cm traces, image to 0.6 m at 2.5 mm)."""
    print(f"machine: {_machine()}")
    z = depth_axis(CFG.depth_max_m)
    for n_traces in (100, 1000):
        centres = np.arange(0.2, n_traces * 0.01, 0.4)
        pipes = [SyntheticTarget(float(x), 0.1 + 0.05 * (k % 5), 0.02) for k, x in enumerate(centres)]
        b = synthetic_bscan(pipes, v_m_per_ns=V, centre_frequency_mhz=900.0, n_traces=n_traces, spacing_m=0.01,
                            samples=512, dt_ns=GPR.dt_ns, t0_ns=1.0, antenna_height_m=GPR.antenna_height_m,
                            tx_rx_offset_m=GPR.tx_rx_offset_m, noise=0.01, footprint_power=3.0)
        data, x = resample_uniform(b, 0.01)
        repeats = 7 if n_traces <= 100 else 3
        for method in ("kirchhoff", "stolt"):
            seconds = _median_seconds(partial(migrate, data, x, b.dt_ns, b.t0_ns, z, V, method=method,
                                              antenna_height_m=GPR.antenna_height_m,
                                              tx_rx_offset_m=GPR.tx_rx_offset_m), repeats)
            print(f"{method:9s} {n_traces:5d} traces x 512 samples -> {len(z)} x {len(x)} image: "
                  f"median {seconds * 1000:8.1f} ms per B-scan")
        seconds = _median_seconds(partial(interpret_bscan, b, GPR, CFG, V), 3)
        print(f"interpret_bscan (known v) {n_traces:5d} traces, {len(pipes)} pipes: median {seconds * 1000:8.1f} ms")

if __name__ == "__main__":
    main()
