"""The completion evaluation's tables: per-case means and medians, and the targets marked met or not."""

from __future__ import annotations

import pytest

pytest.importorskip("torch")

from training import evaluate


def _rows(cd2: list[float], case: str = "tee") -> list[dict[str, object]]:
    return [{"seed": i, "case": case, "cd2": v, "cd1": v, "fscore": 0.5} for i, v in enumerate(cd2)]


def test_summary_has_the_mean_and_the_median_overall_and_per_case() -> None:
    summary = evaluate.summarise(_rows([1e-3, 2e-3, 30e-3]) + _rows([4e-3], "bend"))
    assert summary["all"]["n"] == 4 and summary["tee"]["n"] == 3 and "straight" not in summary
    assert summary["tee"]["cd2_e3"] == pytest.approx(11.0)
    assert summary["tee"]["median_cd2_e3"] == pytest.approx(2.0)  # the outlier moves the mean, not the median


def test_targets_compare_gprnet_with_each_baseline_at_the_issue_margins() -> None:
    def table(cd2_e3: float) -> dict[str, dict[str, float]]:
        return {case: {"cd2_e3": cd2_e3} for case in ("all", *evaluate.CASES)}

    report = {"table1": {"gprnet": table(0.88), "pcn": table(1.0), "pfnet": table(0.8), "geometric": table(0.9)},
              "latency": {"gprnet": {"onnxruntime_ms": 120.0}}}
    lines = evaluate.targets(report)
    assert any("PCN CD2 = 0.880 (target ≤ 0.89): met" in line for line in lines)
    assert any("PF-Net CD2 = 1.100 (target ≤ 1.0): NOT met" in line for line in lines)
    assert any("beats the geometric fit on CD2 in: straight" in line for line in lines)
    assert any("120.0 ms (target ≤ 100 ms): NOT met" in line for line in lines)


def test_a_seeds_gprnet_is_set_against_the_baselines_of_the_same_seed() -> None:
    def table(cd2_e3: float) -> dict[str, dict[str, float]]:
        return {case: {"cd2_e3": cd2_e3} for case in ("all", *evaluate.CASES)}

    report = {"table1": {"gprnet": table(1.0), "pcn": table(1.0), "pfnet": table(1.0), "geometric": table(0.5),
                         "gprnet_s1": table(2.0), "pcn_s1": table(2.5), "pfnet_s1": table(1.6)},
              "latency": {}}
    lines = evaluate.targets(report)
    assert any("gprnet_s1 CD2 / pcn_s1 CD2 = 0.800 (target ≤ 0.89): met" in line for line in lines)
    assert any("gprnet_s1 CD2 / pfnet_s1 CD2 = 1.250 (target ≤ 1.0): NOT met" in line for line in lines)
    assert not any("gprnet_s1 CD2 / PCN" in line for line in lines)  # not seed 0's baseline
