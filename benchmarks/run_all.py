"""Run every benchmark in turn (`make bench`); each prints its own figures and the machine."""

from __future__ import annotations

import importlib
import sys
import time

BENCHMARKS = (
    "bench_forward",
    "bench_migration",
    "bench_chain",
    "bench_parsers_gpr",
    "bench_parsers_motors",
    "bench_realsense",
    "bench_fusion",
    "bench_replay",
    "bench_outputs",
)


def main(names: list[str]) -> int:
    """Run the named benchmarks (all when none are named)."""
    for name in names or BENCHMARKS:
        print(f"\n=== {name} ===", flush=True)
        start = time.perf_counter()
        module = importlib.import_module(f"benchmarks.{name}")
        sys.argv = [name]  # benchmarks with their own flags get their defaults
        module.main()
        print(f"({name}: {time.perf_counter() - start:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
