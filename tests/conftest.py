"""Shared test fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
REAL_DZT = SHARED_DATA / "real" / "FILE____032.DZT"


@pytest.fixture
def real_dzt() -> Path:
    """The real GSSI SIR-3000 file shipped in ../shared/data (skips if the checkout lacks it)."""
    if not REAL_DZT.exists():
        pytest.skip(f"{REAL_DZT} not present")
    return REAL_DZT
