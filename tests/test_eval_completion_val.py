"""training.eval_completion_val: interpreted val surveys cached once, then the completion re-scored from them."""

from __future__ import annotations

from pathlib import Path

import pytest

from training import eval_completion_val as ecv


def test_an_empty_cache_says_how_to_fill_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ecv, "CACHE", tmp_path)
    with pytest.raises(SystemExit, match=r"training\.eval_completion_val cache --method classical"):
        ecv.score("classical", "geometric")


@pytest.mark.slow
def test_a_cached_survey_is_scored_and_not_interpreted_twice(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ecv, "CACHE", tmp_path)
    folder = ecv.build_cache("classical", limit=1)
    (cached,) = folder.glob("*.pkl")
    stamp = cached.stat().st_mtime_ns
    ecv.build_cache("classical", limit=1)
    assert cached.stat().st_mtime_ns == stamp
    totals = ecv.score("classical", "geometric")
    (case, (found, true, extra)), = totals.items()
    assert case in ecv.CASES and true >= 1 and 0 <= found <= true and extra >= 0
