"""Property-based fuzzing of the DZT reader on mutated headers of real files (issue 13, item 2).

Seeds: every real DZT in ../shared/data/real (header + its first scans) and the byte-built SIR-4000
and 1999 files. Mutations: header bytes overwritten, header fields set to extreme values (0, -1,
NaN, ±inf, 1e-30, 1e30, 0x7FFF, ...), files cut or extended. 2,200 examples in all, derandomized.

Asserted for every example: the reader either returns a sound file or raises DataFormatError
(never another exception); building the B-scan from it (gpr.bscan.bscan_from_dzt and
interpret_file.dzt_bscan + gpr_config_for) raises nothing but GprbotError and gives finite
positive dt and spacing; each parse takes < 1 s and its peak traced memory stays under
8 x the file's size + 2 MiB (tracemalloc).
"""

from __future__ import annotations

import functools
import math
import struct
import time
import tracemalloc
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gprbot.apps import interpret_file
from gprbot.config import GprConfig, load_config
from gprbot.errors import DataFormatError, GprbotError
from gprbot.gpr.bscan import bscan_from_dzt
from gprbot.gpr.dzt import parse_dzt
from gprbot.gpr.dzt_header import MAX_DT_NS, MAX_SAMPLES, MIN_DT_NS

from .conftest import fuzz_examples
from .test_dzt_real import FILES
from .test_dzt_variants import file_1999_bytes, sir4000_bytes

SEED_SCANS = 48  # scans kept of each real file: mutations are in the header, the data only need to exist
MAX_SECONDS = 1.0
MEMORY_FACTOR, MEMORY_SLACK = 8, 2 * 2**20
STATS: dict[str, Any] = {
    "examples": 0, "accepted": 0, "refused": 0, "bscans": 0, "peak_bytes": 0, "peak_ratio_64k": 0.0, "slowest_s": 0.0
}  # fmt: skip

FIELDS = [  # (offset, struct format) of the header fields that size, divide or describe
    (0, "<H"), (2, "<h"), (4, "<H"), (6, "<h"), (8, "<h"), (10, "<f"), (14, "<f"), (18, "<f"), (22, "<f"),
    (26, "<f"), (32, "<I"), (40, "<H"), (42, "<H"), (44, "<H"), (46, "<H"), (52, "<h"), (54, "<f"), (62, "<f"),
]  # fmt: skip
INTS = [0, 1, 2, 3, 4, 7, 8, 15, 16, 17, 24, 31, 32, 64, 255, 256, 1023, 1024, 1025, 2048, 0x7FFF, 0x8000, 0xFFFF]
FLOATS = [0.0, -0.0, -1.0, 1.0, 1e-30, 1e30, 1e-6, 1e5, 9999.0, 10001.0, math.nan, math.inf, -math.inf, 3.4e38]


@functools.cache
def seeds() -> tuple[bytes, ...]:
    out = [sir4000_bytes(traces=24), sir4000_bytes(traces=12, channels=2), file_1999_bytes()]
    for path in FILES.values():
        if path.exists():
            raw = path.read_bytes()
            dzt = parse_dzt(raw)
            scan = dzt.header.channels * dzt.header.samples * dzt.header.bits // 8
            out.append(raw[: dzt.header.data_offset + SEED_SCANS * scan])
    return tuple(out)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    tracemalloc.start()
    yield tmp_path_factory.mktemp("fuzz")
    tracemalloc.stop()
    print(f"\nDZT fuzz: {STATS}")


@functools.cache
def base_gpr() -> GprConfig:
    return load_config().gpr


def exercise(raw: bytes, workdir: Path) -> None:
    """One mutated file through the reader and the B-scan construction, with the bounds asserted."""
    STATS["examples"] += 1
    tracemalloc.reset_peak()
    start_mem = tracemalloc.get_traced_memory()[0]
    started = time.perf_counter()
    try:
        dzt = parse_dzt(raw, allow_partial=True)
    except DataFormatError as exc:
        STATS["refused"] += 1
        assert "\n" not in str(exc)
        dzt = None
    elapsed = time.perf_counter() - started
    peak = tracemalloc.get_traced_memory()[1] - start_mem
    STATS["peak_bytes"] = max(STATS["peak_bytes"], peak)
    if len(raw) >= 65536:  # the ratio of tiny (cut) files is all fixed overhead, bounded by the slack
        STATS["peak_ratio_64k"] = max(STATS["peak_ratio_64k"], peak / len(raw))
    STATS["slowest_s"] = max(STATS["slowest_s"], elapsed)
    assert elapsed < MAX_SECONDS
    assert peak < MEMORY_FACTOR * len(raw) + MEMORY_SLACK
    if dzt is None:
        return
    STATS["accepted"] += 1
    h = dzt.header
    assert h.traces >= 1 and 2 <= h.samples <= MAX_SAMPLES and MIN_DT_NS <= h.dt_ns <= MAX_DT_NS
    assert all(c.shape == (h.samples, h.traces) for c in dzt.channels)
    assert all(math.isfinite(v) for v in (h.traces_per_m, h.traces_per_s, h.eps_r, h.position_ns, h.depth_m))
    assert all(0 <= k < h.traces for k in dzt.marks)
    try:
        bscan = bscan_from_dzt(dzt)
        assert np.isfinite(bscan.positions).all() and math.isfinite(bscan.dt_ns) and bscan.dt_ns > 0
    except GprbotError:
        pass
    path = workdir / "mutated.dzt"
    path.write_bytes(raw)
    for spacing in (None, 0.05):
        try:
            bscan, described = interpret_file_bscan(path, spacing)
            assert np.isfinite(bscan.positions).all() and bscan.dt_ns > 0
            STATS["bscans"] += 1
            gpr = interpret_file.gpr_config_for(described, base_gpr(), None)
            assert 10.0 <= gpr.centre_frequency_mhz <= 10_000.0
        except GprbotError:
            pass


def interpret_file_bscan(path: Path, spacing: float | None) -> tuple[Any, Any]:
    """`gprbot interpret`'s B-scan construction: file_bscan (any format) or, before it, dzt_bscan."""
    build = getattr(interpret_file, "file_bscan", None) or interpret_file.dzt_bscan
    return build(path, 0, spacing, allow_partial=True)  # type: ignore[no-any-return]


def fuzz(examples: int) -> settings:
    """A fixed number of derandomized examples, no deadline (time is bounded per parse instead)."""
    return settings(
        max_examples=examples, deadline=None, derandomize=True, database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.function_scoped_fixture],
    )  # fmt: skip

header_positions = st.one_of(st.integers(0, 127), st.integers(0, 1023))


@fuzz(fuzz_examples(300, 900))
@given(st.data(), st.lists(st.tuples(header_positions, st.integers(0, 255)), min_size=1, max_size=8))
def test_overwritten_header_bytes(workdir: Path, data: st.DataObject, edits: list[tuple[int, int]]) -> None:
    raw = bytearray(data.draw(st.sampled_from(seeds())))
    for position, value in edits:
        raw[position] = value
    exercise(bytes(raw), workdir)


@fuzz(fuzz_examples(300, 900))
@given(
    st.data(),
    st.lists(
        st.tuples(st.sampled_from(FIELDS), st.one_of(st.sampled_from(INTS), st.integers(-(2**31), 2**32 - 1)),
                  st.one_of(st.sampled_from(FLOATS), st.floats(width=32))),
        min_size=1, max_size=4,
    ),
)  # fmt: skip
def test_extreme_header_fields(workdir: Path, data: st.DataObject, edits: list[tuple[Any, int, float]]) -> None:
    raw = bytearray(data.draw(st.sampled_from(seeds())))
    for (offset, fmt), integer, real in edits:
        if fmt == "<f":
            struct.pack_into(fmt, raw, offset, real)
        else:
            bits = struct.calcsize(fmt) * 8
            value = integer % (1 << bits)
            if fmt[1].islower() and value >= 1 << (bits - 1):
                value -= 1 << bits
            struct.pack_into(fmt, raw, offset, value)
    exercise(bytes(raw), workdir)


@fuzz(fuzz_examples(150, 400))
@given(st.data(), st.floats(0.0, 1.0), st.binary(max_size=3000), st.booleans())
def test_cut_and_extended_files(workdir: Path, data: st.DataObject, cut: float, tail: bytes, extend: bool) -> None:
    raw = data.draw(st.sampled_from(seeds()))
    raw = raw + tail if extend else raw[: int(cut * len(raw))]
    exercise(raw, workdir)


def test_seeds_cover_the_real_files_and_the_synthetic_ones() -> None:
    present = sum(path.exists() for path in FILES.values())
    assert len(seeds()) == 3 + present
