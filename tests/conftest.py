"""Shared test fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
REAL_DZT = SHARED_DATA / "real" / "FILE____032.DZT"


def fuzz_examples(suite: int, deep: int) -> int:
    """Examples a slow fuzz test draws: `suite` in `make test` (its ten minutes), `deep` with GPRBOT_FUZZ=deep.

    The draws are derandomized, so the suite's are a fixed set; `benchmarks.fuzz_parsers` fuzzes for as
    long as it is given.
    """
    return deep if os.environ.get("GPRBOT_FUZZ") == "deep" else suite


@pytest.fixture
def real_dzt() -> Path:
    """The real GSSI SIR-3000 file shipped in ../shared/data (skips if the checkout lacks it)."""
    if not REAL_DZT.exists():
        pytest.skip(f"{REAL_DZT} not present")
    return REAL_DZT
