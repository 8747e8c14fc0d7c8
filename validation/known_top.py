"""`python -m validation.known_top dev|test`: the velocity calibrated on one known top, on the FDTD scenes.

For every target of every scene in turn, the chain is given that target's true top depth and position (as
a user gives a cover meter reading: `gprbot interpret --known-top X:DEPTH`) and calibrates the velocity
on it; printed: the velocity error per target, and per scene, calibrated on its first target along the
line, the pipes found within 3 cm and 1 cm of the other targets — against the chain's own estimate.
"""

from __future__ import annotations

import argparse
import statistics
from dataclasses import dataclass

from gprbot.gpr.chain.calibrate import KnownTop
from gprbot.gpr.chain.run import Interpretation, interpret
from validation.cases import Case, fdtd_cases
from validation.scoring import Found, Score, score


@dataclass(frozen=True)
class Calibration:
    """One target used as the known top: the scene, which target, the velocity error (None: not used)."""

    scene: str
    kind: str
    x_m: float
    top_m: float
    error: float | None  # calibrated / true velocity - 1
    note: str


def _scored(case: Case, known: tuple[KnownTop, ...]) -> tuple[Interpretation, Score]:
    """The chain's interpretation of one scene with the known tops (or none), and its score."""
    bscan, gpr = case.load()
    r = interpret(bscan, gpr, None, known_tops=known)
    found = tuple(Found(d.x_m, d.depth_m, d.radius_m, d.kind) for d in r.detections)
    return r, score(found, case.targets, case.tolerance_m)


def calibrations(case: Case) -> list[Calibration]:
    """The velocity error with each of the scene's targets as the known top."""
    out = []
    assert case.velocity is not None
    for t in case.targets:
        if t.depth_m is None or t.radius_m is None:
            continue
        top = t.depth_m - t.radius_m
        r, _ = _scored(case, (KnownTop(t.x_m, top),))
        v, source = r.velocity, r.velocity_source
        error = v / case.velocity - 1.0 if source == "calibrated" else None
        out.append(Calibration(case.name, t.kind, t.x_m, top, error, source))
    return out


def main(argv: list[str] | None = None) -> int:
    """Print the calibrations and the per-scene scores."""
    parser = argparse.ArgumentParser(prog="python -m validation.known_top", description=__doc__)
    parser.add_argument("half", choices=["dev", "test"])
    args = parser.parse_args(argv)
    cases = [c for c in fdtd_cases() if c.group == f"fdtd-{args.half}" and c.targets]
    rows: list[Calibration] = []
    print("| scene | target | x m | top cm | velocity error |\n|---|---|---|---|---|")
    for case in cases:
        for c in calibrations(case):
            rows.append(c)
            err = f"{100 * c.error:+.1f} %" if c.error is not None else f"not used ({c.note})"
            print(f"| {c.scene} | {c.kind} | {c.x_m:.3f} | {100 * c.top_m:.1f} | {err} |", flush=True)
    used = [abs(c.error) for c in rows if c.error is not None]
    if used:
        print(f"\n{len(rows)} targets as the known top: used on {len(used)}; median |velocity error| "
              f"{100 * statistics.median(used):.1f} %, within 5 % on {sum(e <= 0.05 for e in used)}, within 2 % on "
              f"{sum(e <= 0.02 for e in used)}")
    print("\nPer scene, calibrated on its first target along the line, against the chain's own estimate "
          "(pipes within 3 cm / 1 cm, tops within 1 cm, false pipes):\n")
    print("| scene | v err, estimated | v err, calibrated | estimated | calibrated |\n|---|---|---|---|---|")
    totals = {"estimated": [0, 0, 0, 0, 0], "calibrated": [0, 0, 0, 0, 0]}
    for case in cases:
        assert case.velocity is not None
        first = min((t for t in case.targets if t.depth_m is not None and t.radius_m is not None),
                    key=lambda t: t.x_m)
        assert first.depth_m is not None and first.radius_m is not None
        cells = []
        for label, known in (("estimated", ()), ("calibrated", (KnownTop(first.x_m, first.depth_m - first.radius_m),))):
            r, s = _scored(case, known)
            v = r.velocity
            for k, n in enumerate((s.pipes, s.pipes_within, s.pipes_within_fine, s.tops_within_fine, s.false_pipes)):
                totals[label][k] += n
            cells.append((f"{100 * (v / case.velocity - 1):+.1f} %",
                          f"{s.pipes_within}/{s.pipes} / {s.pipes_within_fine}/{s.pipes} / "
                          f"{s.tops_within_fine}/{s.pipes} / {s.false_pipes}"))
        print(f"| {case.name} | {cells[0][0]} | {cells[1][0]} | {cells[0][1]} | {cells[1][1]} |", flush=True)
    for label, (pipes, within, fine, tops, false) in totals.items():
        print(f"\n{label}: within 3 cm {within}/{pipes}, within 1 cm {fine}/{pipes}, tops within 1 cm {tops}/{pipes}, "
              f"false pipes {false / len(cases):.2f} a scene", end="")
    print()
    _two_tops(cases)
    return 0


def _two_tops(cases: list[Case]) -> None:
    """Scenes with targets at two depths: the shallowest and the deepest top known, against each alone."""
    print("\nTwo known tops (the shallowest and the deepest target), against each alone:\n")
    print("| scene | tops cm | v err, two | time zero moved | v err, shallow alone | v err, deep alone |"
          " two: within 3 cm / 1 cm / tops / false |\n|---|---|---|---|---|---|---|")
    two_errors, alone_errors = [], []
    for case in cases:
        assert case.velocity is not None
        known = [t for t in case.targets if t.depth_m is not None and t.radius_m is not None]
        if len(known) < 2:
            continue
        ends = sorted(known, key=lambda t: t.depth_m - t.radius_m)  # type: ignore[operator]
        tops = tuple(KnownTop(t.x_m, t.depth_m - t.radius_m) for t in (ends[0], ends[-1]))  # type: ignore[operator]
        if tops[1].top_m - tops[0].top_m < 0.05:
            continue
        r, s = _scored(case, tops)
        two_point = r.velocity_source == "calibrated" and "known tops" in r.velocity_method
        errs = []
        for k in tops:
            alone, _ = _scored(case, (k,))
            calibrated = alone.velocity_source == "calibrated"
            errs.append(f"{100 * (alone.velocity / case.velocity - 1):+.1f} %" if calibrated else "not used")
            if calibrated:
                alone_errors.append(abs(alone.velocity / case.velocity - 1))
        err = f"{100 * (r.velocity / case.velocity - 1):+.1f} %" if two_point else "not two-point"
        if two_point:
            two_errors.append(abs(r.velocity / case.velocity - 1))
        moved = r.prepared.t0_method.split("moved ")[-1].split(" by")[0] if "moved" in r.prepared.t0_method else "–"
        print(f"| {case.name} | {100 * tops[0].top_m:.1f}, {100 * tops[1].top_m:.1f} | {err} | {moved} | {errs[0]} | "
              f"{errs[1]} | {s.pipes_within}/{s.pipes} / {s.pipes_within_fine}/{s.pipes} / {s.tops_within_fine}/"
              f"{s.pipes} / {s.false_pipes} |", flush=True)
    if two_errors:
        print(f"\ntwo tops: median |velocity error| {100 * statistics.median(two_errors):.1f} % on {len(two_errors)} "
              f"scenes; each alone: {100 * statistics.median(alone_errors):.1f} % on {len(alone_errors)} calibrations")


if __name__ == "__main__":
    raise SystemExit(main())
