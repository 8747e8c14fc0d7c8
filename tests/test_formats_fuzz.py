"""Mutated headers of the real DT1, RD3, SU, gprMax files (and a SEG-Y we write): a Radargram or one DataFormatError.

Each example mutates header bytes or header values (and sometimes cuts the file), reads it through
detection, and checks: no other exception, one line of error text, bounded memory (tracemalloc peak,
numpy included) and time. 400 examples per format, 2,000 in all; on the 2-core dev machine the
whole file runs in about a minute.
"""

from __future__ import annotations

import tempfile
import time
import tracemalloc
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gprbot.errors import DataFormatError
from gprbot.gpr.formats import Radargram, read_radargram, write_radargram
from tests.conftest import SHARED_DATA, fuzz_examples

REAL = SHARED_DATA / "real"
EXAMPLES = 400
MAX_PEAK_BYTES = 300 * 2**20  # a read may allocate at most this (the files are ≤ 4 MB)
MAX_SECONDS = 5.0
pytestmark = [pytest.mark.slow, pytest.mark.skipif(not REAL.exists(), reason=f"{REAL} not present")]

EXTREMES = ["0", "-1", "1", "0.0001", "1e-30", "1e30", "nan", "inf", "-inf", "65537", "99999999999", "abc", "", "3.5"]
FUZZ = settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)

byte_edits = st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), min_size=1, max_size=8)
cut = st.one_of(st.none(), st.integers(1, 5000))


@cache
def real(name: str) -> bytes:
    """Bytes of a real file (or of our SEG-Y made from the real SU file)."""
    if name == "segy":
        su = read_radargram(REAL / "su_trench_pipes_matgpr" / "trench_and_pipes.su")
        small = Radargram(samples=su.samples[:64], dt_ns=su.dt_ns, source_format="su", positions_m=su.positions_m[:64])
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "x.sgy"
            write_radargram(path, small)
            return path.read_bytes()
    return (REAL / name).read_bytes()


def mutate(raw: bytes, edits: list[tuple[int, int]], region: int, chop: int | None) -> bytes:
    """Set bytes at offsets within the first `region` bytes; optionally cut `chop` bytes off the end."""
    out = bytearray(raw)
    for offset, value in edits:
        out[offset % region] = value
    return bytes(out[: len(out) - chop] if chop else out)


def mutate_text(text: str, key_index: int, value: str, sep: str) -> str:
    """Replace the value of one KEY<sep>value line of a text header."""
    lines = text.splitlines()
    keyed = [i for i, ln in enumerate(lines) if sep in ln]
    i = keyed[key_index % len(keyed)]
    lines[i] = lines[i].split(sep, 1)[0] + sep + value
    return "\r\n".join(lines)


def read_bounded(path: Path) -> None:
    """Read `path`: a sane Radargram or one DataFormatError line, within memory and time."""
    tracemalloc.start()
    start = time.perf_counter()
    try:
        rg = read_radargram(path)
    except DataFormatError as exc:
        assert "\n" not in str(exc)
    else:
        assert rg.samples.ndim == 2 and rg.samples.dtype == np.float32 and np.isfinite(rg.samples).all()
        assert np.isfinite(rg.dt_ns) and rg.dt_ns > 0
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    assert peak < MAX_PEAK_BYTES and time.perf_counter() - start < MAX_SECONDS


@FUZZ
@given(byte_edits, st.integers(0, 30), st.sampled_from(EXTREMES), cut)
def test_dt1(edits: list[tuple[int, int]], key: int, value: str, chop: int | None) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "f.DT1"
        path.write_bytes(mutate(real("pulseekko_dt1_rgpr_negative/yyline3.DT1"), edits, 128, chop))
        hd = real("pulseekko_dt1_rgpr_negative/yyline3.HD").decode("latin-1")
        path.with_suffix(".HD").write_text(mutate_text(hd, key, value, "="), "latin-1")
        read_bounded(path)


@FUZZ
@given(st.integers(0, 60), st.sampled_from(EXTREMES), cut)
def test_rd3(key: int, value: str, chop: int | None) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "f.rd3"
        path.write_bytes(mutate(real("mala_rd3_250mhz_matgpr/DAT_0097.rd3"), [], 1, chop))
        rad = real("mala_rd3_250mhz_matgpr/DAT_0097.rad").decode("latin-1")
        path.with_suffix(".rad").write_text(mutate_text(rad, key, value, ":"), "latin-1")
        read_bounded(path)


@FUZZ
@given(byte_edits, cut)
def test_su(edits: list[tuple[int, int]], chop: int | None) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "f.su"
        path.write_bytes(mutate(real("su_trench_pipes_matgpr/trench_and_pipes.su"), edits, 240, chop))
        read_bounded(path)


@FUZZ
@given(byte_edits, st.booleans(), cut)
def test_segy(edits: list[tuple[int, int]], in_binary: bool, chop: int | None) -> None:
    raw = real("segy")
    edits = [((3200 + o % 400) if in_binary else (3600 + o % 240), v) for o, v in edits]
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "f.sgy"
        path.write_bytes(mutate(raw, edits, len(raw), chop))
        read_bounded(path)


# Each draw parses a 4 MB HDF5 file (~70 ms): fewer of them in the suite.
@settings(FUZZ, max_examples=fuzz_examples(100, EXAMPLES))
@given(byte_edits)
def test_gprmax(edits: list[tuple[int, int]]) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "f.out"
        path.write_bytes(mutate(real("gprmax_cylinder_2d/cylinder_Bscan_2D_merged.out"), edits, 4096, None))
        read_bounded(path)
