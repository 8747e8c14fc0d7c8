"""Long fuzz of every boundary parser (the targets of tests/fuzz_targets.py): random bytes and mutated
valid inputs for `--seconds` per parser; prints inputs/s and every failure (input saved under --out).
Run: `python -m benchmarks.fuzz_parsers --seconds 60`.
"""

from __future__ import annotations

import argparse
import random
import time
import traceback
from pathlib import Path

from benchmarks.machine import machine_description
from tests.fuzz_targets import SAMPLE_LOG, TARGETS

SEEDS = [b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n5\r\nhello\r\n0\r\n\r\n",
         b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\n\r\n{}", b"auth 'x\"y\\z'\nestop\njog 0.1 0 1\n",
         b"ok pull 3 " + b"a" * 64 + b"\nabc", b"gpr: {samples: 512}\nshell: {port: 7878, max_clients: 3}\n",
         SAMPLE_LOG]


def mutate(rng: random.Random) -> bytes:
    """Random bytes, or a seed input with bytes flipped, inserted, deleted or repeated."""
    if rng.random() < 0.3:
        return rng.randbytes(rng.randint(0, 2048))
    data = bytearray(rng.choice(SEEDS))
    for _ in range(rng.randint(1, 8)):
        at = rng.randint(0, len(data))
        op = rng.random()
        if op < 0.3 and data:
            data[min(at, len(data) - 1)] ^= 1 << rng.randint(0, 7)
        elif op < 0.6:
            data[at:at] = rng.randbytes(rng.randint(1, 16))
        elif op < 0.8:
            del data[at:at + rng.randint(1, 16)]
        else:
            data[at:at] = data[at:at + rng.randint(1, 64)] * rng.randint(2, 50)
    return bytes(data)


def main() -> None:
    """Fuzz each parser for the given time."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("fuzz-failures"))
    args = parser.parse_args()
    print(machine_description())
    print(f"{'parser':>18} {'inputs':>9} {'inputs/s':>9} {'failures':>9} {'slowest ms':>11}")
    for name, target in TARGETS.items():
        rng = random.Random(f"{args.seed}-{name}")
        count = failures = 0
        slowest = 0.0
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            data = mutate(rng)
            began = time.perf_counter()
            try:
                target(data)
            except Exception:
                failures += 1
                args.out.mkdir(exist_ok=True)
                (args.out / f"{name}-{failures}.bin").write_bytes(data)
                if failures <= 3:
                    traceback.print_exc()
            slowest = max(slowest, time.perf_counter() - began)
            count += 1
        print(f"{name:>18} {count:>9} {count / args.seconds:>9.0f} {failures:>9} {slowest * 1000:>11.1f}")


if __name__ == "__main__":
    main()
