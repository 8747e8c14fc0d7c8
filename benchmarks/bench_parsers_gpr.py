"""Throughput of the GPR trace-stream parser beside the NIC-500's real trace rate.

Frames a stream of SPIDAR SDK-mode traces (20-byte header + float32 samples) for 512 and 1024 samples
per trace, fed as the driver reads the socket (64 KiB chunks) and one trace per read, clean and with a
noise burst every 100 traces (a resync each). Prints medians in traces/s and the share of one core the
parser would take at the device's fastest rate (trigger period >= 1.25 ms, i.e. <= 800 traces/s; a
robot survey runs at 100-400). Then adversarial garbage (back-to-back plausible headers with NaN samples,
every one a candidate that fails): total time and the longest single 64 KiB read, which is how long
the event loop stalls. Run: `.venv/bin/python -m benchmarks.bench_parsers_gpr`.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from benchmarks.machine import machine_description
from gprbot.drivers.gpr.trace_stream import HEADER, TraceFrame, TraceStreamParser, encode_frame

DEVICE_MAX_RATE_HZ = 800.0  # 1 / 0.00125 s, the shortest trigger period of api/nic/setup
SURVEY_RATE_HZ = 100.0  # survey.trace_rate_hz of the default config
STACKS = 4




def make_stream(samples: int, traces: int, noise_every: int | None) -> bytes:
    """`traces` frames of realistic amplitudes, with 37 random bytes before every `noise_every`-th."""
    rng = np.random.default_rng(0)
    data = rng.normal(0.0, 20.0, (traces, samples)).astype(np.float32)
    parts = []
    for n in range(1, traces + 1):
        if noise_every and n % noise_every == 0:
            parts.append(rng.integers(0, 256, 37, dtype=np.uint8).tobytes())
        parts.append(encode_frame(n, data[n - 1], 1_700_000_000 + n // 100, (n % 100) * 10_000_000, STACKS))
    return b"".join(parts)


def time_parse(stream: bytes, samples: int, chunk: int, repeats: int) -> tuple[float, int]:
    """Median seconds to parse the stream, and the traces it yields."""
    durations, count = [], 0
    for _ in range(repeats):
        parser = TraceStreamParser(samples, STACKS)
        start = time.perf_counter()
        events = []
        for i in range(0, len(stream), chunk):
            events += parser.feed(stream[i : i + chunk])
        events += parser.close()
        durations.append(time.perf_counter() - start)
        count = sum(isinstance(e, TraceFrame) for e in events)
    return statistics.median(durations), count


def main() -> None:
    """Print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--traces", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(machine_description())
    print(f"{args.traces} traces per run, median of {args.repeats} runs; stacks={STACKS}")
    print(f"{'samples':>7} {'stream':>7} {'read size':>10} {'traces/s':>10} {'MB/s':>7} "
          f"{'core at 800 Hz':>15} {'core at 100 Hz':>15}")
    for samples in (512, 1024):
        frame_bytes = 20 + 4 * samples
        for label, noise_every in (("clean", None), ("noisy", 100)):
            stream = make_stream(samples, args.traces, noise_every)
            for chunk_label, chunk in (("64 KiB", 64 * 1024), ("1 trace", frame_bytes)):
                seconds, count = time_parse(stream, samples, chunk, args.repeats)
                rate = count / seconds
                print(f"{samples:>7} {label:>7} {chunk_label:>10} {rate:>10.0f} {len(stream) / seconds / 1e6:>7.1f} "
                      f"{DEVICE_MAX_RATE_HZ / rate:>14.2%} {SURVEY_RATE_HZ / rate:>14.2%}")
    print_adversarial(args.repeats)


def adversarial_garbage(size: int) -> bytes:
    """Plausible headers (stacks 1) every 24 bytes, each followed by a NaN: the resync's worst case."""
    unit = HEADER.pack(1_700_000_000, 0, 1, 0, 1, 20) + b"\xff\xff\xff\xff"
    return (unit * (size // len(unit) + 1))[:size]


def time_adversarial(size: int, chunk: int, repeats: int) -> tuple[float, float]:
    """Median total seconds and median longest single read for `size` bytes of garbage."""
    data = adversarial_garbage(size)
    totals, worst = [], []
    for _ in range(repeats):
        parser = TraceStreamParser(512, stacks=1)
        longest = 0.0
        start = time.perf_counter()
        for i in range(0, len(data), chunk):
            began = time.perf_counter()
            parser.feed(data[i : i + chunk])
            longest = max(longest, time.perf_counter() - began)
        parser.close()
        totals.append(time.perf_counter() - start)
        worst.append(longest)
    return statistics.median(totals), statistics.median(worst)


def print_adversarial(repeats: int) -> None:
    """The resync's cost on adversarial garbage: linear in its length, bounded per read."""
    print(f"adversarial garbage (512 samples, stacks 1), median of {repeats} runs")
    print(f"{'garbage':>9} {'read size':>10} {'total s':>9} {'longest read ms':>16} {'us/KiB':>8}")
    for size, chunk in ((93 * 1024, 93 * 1024), (64 * 1024, 64 * 1024), (1024 * 1024, 64 * 1024),
                        (4 * 1024 * 1024, 64 * 1024)):
        total, longest = time_adversarial(size, chunk, repeats)
        print(f"{size // 1024:>6} KiB {chunk // 1024:>6} KiB {total:>9.4f} {longest * 1000:>16.1f} "
              f"{total / (size / 1024) * 1e6:>8.1f}")


if __name__ == "__main__":
    main()
