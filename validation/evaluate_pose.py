"""Evaluation of pose estimation on simulated runs: ATE and yaw drift per estimator → JSON + markdown.

    python -m validation.evaluate_pose --out DIR [--quick] [--seed N]

Runs a 10-line survey (SurveyConfig defaults: 2 m × 0.9 m, 0.1 m/s) and a 5-minute random jog, with
the simulated D435i (IMU + rendered RGB-D → VO) and wheel encoders, and compares the fused filter
with VO only, wheel odometry only and IMU dead reckoning. Errors are taken against ground truth at
10 Hz with no alignment: every estimator starts from the known start pose (odom is defined by it),
which is how the survey uses them. ATE is the RMS horizontal position error (the GPR trace's
placement); the 3-D figure and the final yaw error ("yaw drift") are reported beside it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from gprbot.config import SurveyConfig
from gprbot.fusion.interpolate import interpolate_poses
from gprbot.fusion.so3 import quat_to_matrix, yaw_of
from gprbot.messages import Pose
from gprbot.motion.planner import plan_survey
from gprbot.sim.motion_truth import GroundTruth, jog_ground_truth, survey_ground_truth
from gprbot.simulated.sensor_runs import Estimates, SimulatedRun, run_estimators, simulate_run

METHODS = ("fused", "vo", "wheels", "imu")
LABELS = {"fused": "fused (IMU + VO + wheels)", "vo": "VO only", "wheels": "wheel odometry only",
          "imu": "IMU dead reckoning"}


@dataclass(frozen=True)
class Metrics:
    """Errors of one estimator on one run."""

    ate_cm: float
    ate_3d_cm: float
    max_error_cm: float
    final_error_cm: float
    yaw_drift_deg: float
    yaw_rms_deg: float


def trajectory_metrics(poses: list[Pose], truth: GroundTruth, t_from: float, rate_hz: float = 10.0) -> Metrics:
    """Errors against truth on a common grid from t_from to the end of the estimate."""
    stamps = np.array([p.t for p in poses])
    t = np.arange(max(t_from, stamps[0]), min(truth.t_end, stamps[-1]), 1.0 / rate_hz)
    est = interpolate_poses(poses, t)
    error = np.stack([p.position for p in est]) - truth.position(t)
    true_R = truth.rotation(t)
    yaw_error = np.degrees([
        math.remainder(yaw_of(quat_to_matrix(p.orientation)) - yaw_of(R), 2.0 * math.pi)
        for p, R in zip(est, true_R, strict=True)
    ])
    horizontal = np.linalg.norm(error[:, :2], axis=1)
    return Metrics(
        ate_cm=100.0 * float(np.sqrt(np.mean(horizontal**2))),
        ate_3d_cm=100.0 * float(np.sqrt(np.mean(np.sum(error**2, axis=1)))),
        max_error_cm=100.0 * float(horizontal.max()),
        final_error_cm=100.0 * float(horizontal[-1]),
        yaw_drift_deg=float(abs(yaw_error[-1])),
        yaw_rms_deg=float(np.sqrt(np.mean(yaw_error**2))),
    )


def evaluate_run(run: SimulatedRun) -> dict[str, object]:
    """All estimators on one run: metrics, path length, VO and filter statistics."""
    estimates: Estimates = run_estimators(run)
    t_from = run.truth.t_start + 0.5
    samples = run.truth.position(np.arange(run.truth.t_start, run.truth.t_end, 0.05))
    return {
        "duration_s": round(run.truth.t_end - run.truth.t_start, 1),
        "path_m": round(float(np.sum(np.linalg.norm(np.diff(samples[:, :2], axis=0), axis=1))), 2),
        "frames": run.frames,
        "vo_lost_fraction": round(run.vo_lost_frames / max(run.frames, 1), 3),
        "vo_ms_per_frame": round(run.vo_ms_per_frame, 2),
        "render_ms_per_frame": round(run.render_ms_per_frame, 2),
        "filter_s": round(estimates.filter_s, 2),
        "filter_stats": asdict(estimates.stats),
        "methods": {name: asdict(trajectory_metrics(getattr(estimates, name), run.truth, t_from)) for name in METHODS},
    }


def check_targets(survey: dict[str, object]) -> dict[str, bool]:
    """The survey targets: fused ATE ≤ 1 cm, yaw drift ≤ 0.5°, each ≤ half the best single source."""
    methods = survey["methods"]
    assert isinstance(methods, dict)
    fused, singles = methods["fused"], [methods[m] for m in ("vo", "wheels", "imu")]
    best_ate = min(s["ate_cm"] for s in singles)
    best_yaw = min(s["yaw_drift_deg"] for s in singles)
    return {
        "fused_ate_le_1cm": fused["ate_cm"] <= 1.0,
        "fused_yaw_drift_le_0.5deg": fused["yaw_drift_deg"] <= 0.5,
        "fused_ate_le_half_best_single": fused["ate_cm"] <= 0.5 * best_ate,
        "fused_yaw_drift_le_half_best_single": fused["yaw_drift_deg"] <= 0.5 * best_yaw,
    }


def markdown(report: dict[str, object]) -> str:
    """The report as markdown tables, one per scenario."""
    lines = ["# Pose estimation on simulated runs", "", f"Machine: {report['machine']}", ""]
    scenarios = report["scenarios"]
    assert isinstance(scenarios, dict)
    for name, scenario in scenarios.items():
        lines += [
            f"## {name}: {scenario['duration_s']} s, {scenario['path_m']} m driven, "
            f"VO lost on {100 * scenario['vo_lost_fraction']:.1f} % of {scenario['frames']} frames",
            "",
            "| estimator | ATE (cm RMS) | ATE 3-D (cm) | max (cm) | final (cm) | yaw drift (°) | yaw RMS (°) |",
            "|---|---:|---:|---:|---:|---:|---:|",
        ]
        for method, m in scenario["methods"].items():
            lines.append(
                f"| {LABELS[method]} | {m['ate_cm']:.3f} | {m['ate_3d_cm']:.3f} | {m['max_error_cm']:.3f} | "
                f"{m['final_error_cm']:.3f} | {m['yaw_drift_deg']:.3f} | {m['yaw_rms_deg']:.3f} |"
            )
        lines += ["", f"Filter: {scenario['filter_stats']}", ""]
    lines += ["## Targets (10-line survey)", ""]
    targets = report["targets"]
    assert isinstance(targets, dict)
    lines += [f"- {key}: {'met' if ok else 'NOT met'}" for key, ok in targets.items()]
    return "\n".join(lines) + "\n"


def scenario_truths(quick: bool, seed: int) -> dict[str, GroundTruth]:
    """The two simulated runs: a survey of SurveyConfig defaults (3 lines if quick) and a random jog."""
    survey_cfg = SurveyConfig(lines=3) if quick else SurveyConfig()
    jog_s = 60.0 if quick else 300.0
    return {
        f"survey ({survey_cfg.lines} lines)": survey_ground_truth(plan_survey(survey_cfg), seed=seed),
        f"random jog ({jog_s:.0f} s)": jog_ground_truth(jog_s, seed=seed),
    }


def _evaluate_scenario(name: str, quick: bool, seed: int) -> dict[str, object]:
    cv2.setNumThreads(1)  # one scenario per process and core
    return evaluate_run(simulate_run(name, scenario_truths(quick, seed)[name], seed))


def evaluate(out: Path, quick: bool = False, seed: int = 0, jobs: int = 2) -> dict[str, object]:
    """Run both scenarios (in `jobs` processes), write fusion_eval.json and .md into `out`, return the report."""
    began = time.perf_counter()
    names = list(scenario_truths(quick, seed))
    if jobs > 1:
        with ProcessPoolExecutor(max_workers=min(jobs, len(names))) as pool:
            results = list(pool.map(_evaluate_scenario, names, [quick] * len(names), [seed] * len(names)))
    else:
        results = [_evaluate_scenario(name, quick, seed) for name in names]
    scenarios = dict(zip(names, results, strict=True))
    report: dict[str, object] = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.python_implementation()} "
                   f"{platform.python_version()}, {platform.platform()}",
        "seed": seed,
        "quick": quick,
        "scenarios": scenarios,
        "targets": check_targets(scenarios[names[0]]),
    }
    report["wall_s"] = round(time.perf_counter() - began, 1)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fusion_eval.json").write_text(json.dumps(report, indent=2))
    (out / "fusion_eval.md").write_text(markdown(report))
    return report


def main(argv: list[str] | None = None) -> int:
    """Command line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="directory for fusion_eval.json and .md")
    parser.add_argument("--quick", action="store_true", help="3 survey lines and a 60 s jog (about a minute)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=2, help="scenarios run in parallel processes (default 2)")
    args = parser.parse_args(argv)
    report = evaluate(args.out, args.quick, args.seed, args.jobs)
    print(markdown(report))
    print(f"wrote {args.out / 'fusion_eval.json'} and {args.out / 'fusion_eval.md'} in {report['wall_s']} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
