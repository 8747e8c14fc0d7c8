"""Benchmark: the interpretation's time per 100-trace B-scan (the chain, and MigrationNet as configured), in-process.

Run: .venv/bin/python -m benchmarks.bench_chain — medians over B-scans of 100 traces: analytic lines
(three pipes and a rebar row, 900 MHz, 512 samples), 100-trace pieces of the committed FDTD scenes
(padded by repetition where shorter), and of the real StructureScan line; the stage split of one run.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from benchmarks.machine import machine_description
from gprbot.config import Config, GprConfig
from gprbot.gpr.bscan import BScan, SyntheticTarget, synthetic_bscan
from gprbot.gpr.chain.candidates import apex_candidates
from gprbot.gpr.chain.prepare import prepare
from gprbot.gpr.chain.reflectors import fit_reflectors
from gprbot.gpr.chain.run import interpret
from gprbot.gpr.chain.velocity import estimate_velocity
from gprbot.infer.pipeline import migrationnet_sizer

TRACES = 100


def _analytic(seed: int) -> tuple[BScan, GprConfig]:
    """A 100-trace line: two pipes and a bar row at random places (900 MHz, 1 cm traces)."""
    rng = np.random.default_rng(seed)
    gpr = replace(GprConfig(), centre_frequency_mhz=900.0, antenna_height_m=0.02, tx_rx_offset_m=0.06)
    targets = [SyntheticTarget(float(rng.uniform(0.15, 0.85)), float(rng.uniform(0.15, 0.35)),
                               float(rng.uniform(0.01, 0.06)), 1.0) for _ in range(2)]
    targets += [SyntheticTarget(0.05 + 0.2 * k, 0.06, 0.006, 0.5) for k in range(5)]
    b = synthetic_bscan(targets, v_m_per_ns=0.1, centre_frequency_mhz=900.0, n_traces=TRACES, spacing_m=0.01,
                        samples=512, dt_ns=0.025, t0_ns=1.0, antenna_height_m=0.02, tx_rx_offset_m=0.06,
                        noise=0.01, direct_wave=3.0, rng=rng)
    return replace(b, t0_ns=math.nan), gpr


def _pieces() -> list[tuple[str, BScan, GprConfig]]:
    """100-trace pieces of the yardsticks' B-scans (FDTD scenes repeated to 100 traces when shorter)."""
    from validation.cases import bscan_along_x, fdtd_cases, real_cases

    out = []
    for case in fdtd_cases() + real_cases():
        b, gpr = case.load()
        data = np.asarray(b.data)
        spacing = float(b.positions[1, 0] - b.positions[0, 0])
        if data.shape[0] < TRACES:
            data = np.concatenate([data] * math.ceil(TRACES / data.shape[0]))[:TRACES]
        else:
            step = max(1, round(0.01 / spacing))  # the chain works on a ≥ 1 cm grid: give it 100 columns
            data, spacing = data[: TRACES * step : step], spacing * step
        out.append((case.name, bscan_along_x(data[:TRACES], b.dt_ns, spacing), gpr))
    return out


def _modes() -> dict[str, Callable[[BScan, GprConfig], object]]:
    """What is timed per B-scan: the chain (velocity estimated, given, and with MigrationNet's radii where the
    curve gives none) and, where validation/ is importable, `interpretation.method: migrationnet` as the product
    runs it (the chain, the network on the section at the chain's velocity, the echo check)."""
    def sized(b: BScan, gpr: GprConfig) -> object:
        return interpret(b, gpr, sizer=migrationnet_sizer(b, replace(Config(), gpr=gpr)))

    modes: dict[str, Callable[[BScan, GprConfig], object]] = {
        "velocity estimated": lambda b, gpr: interpret(b, gpr),
        "velocity given": lambda b, gpr: interpret(b, gpr, 0.1),
        "velocity estimated, radii from MigrationNet where the curve gives none": sized,
    }
    try:
        from validation.methods import run_migrationnet
    except ImportError:
        return modes
    modes["velocity estimated, interpretation.method migrationnet"] = lambda b, gpr: run_migrationnet(b, gpr, None)
    modes["velocity given, interpretation.method migrationnet"] = lambda b, gpr: run_migrationnet(b, gpr, 0.1)
    return modes


def main() -> None:
    """Print the medians (every mode timed on each B-scan in turn, so that a machine whose speed drifts during
    the run weighs on all alike) and one run's stage split."""
    print(f"machine: {machine_description()}")
    lines = [(f"analytic {s}", *_analytic(s)) for s in range(10)]
    try:
        lines += _pieces()
    except ImportError:
        print("(validation/ not importable: analytic lines only)")
    modes = _modes()
    for run in modes.values():  # warm-up: imports, caches, the model loaded once as a process does
        run(lines[0][1], lines[0][2])
    times: dict[str, list[float]] = {name: [] for name in modes}
    cpu: dict[str, list[float]] = {name: [] for name in modes}
    for _, b, gpr in lines:
        for name, run in modes.items():
            start, start_cpu = time.perf_counter(), time.process_time()
            run(b, gpr)
            times[name].append(time.perf_counter() - start)
            cpu[name].append(time.process_time() - start_cpu)
    for name in modes:
        print(f"{len(lines)} B-scans of {TRACES} traces, {name}: median {statistics.median(times[name]) * 1000:.0f} "
              f"ms, p90 {np.percentile(times[name], 90) * 1000:.0f} ms per B-scan "
              f"(median CPU {statistics.median(cpu[name]) * 1000:.0f} ms)")
    _stage_split(lines[0][1], lines[0][2])


def _stage_split(b: BScan, gpr: GprConfig) -> None:
    """Print how one line's time divides between the chain's stages."""
    t = [time.perf_counter()]
    prep = prepare(b, gpr)
    t.append(time.perf_counter())
    cands = apex_candidates(prep)
    t.append(time.perf_counter())
    refl = fit_reflectors(prep, cands)
    t.append(time.perf_counter())
    estimate_velocity(prep, refl)
    t.append(time.perf_counter())
    interpret(b, gpr)
    whole = time.perf_counter() - t[-1]
    names = ("prepare", "candidates", "picks+fits", "velocity")
    split = [(n, b - a) for n, a, b in zip(names, t[:-1], t[1:], strict=True)]
    split.append(("refit, classify, migration, spots", whole - (t[-1] - t[0])))
    print("stages of one analytic line: " + ", ".join(f"{n} {1000 * d:.0f} ms" for n, d in split))


if __name__ == "__main__":
    main()
