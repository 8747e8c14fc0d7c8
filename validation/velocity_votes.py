"""Each velocity voter of the chain on the FDTD dev half, against what a cylinder's radius predicts it votes.

    python -m validation.velocity_votes [--half fdtd-dev]

The chain's velocity (gprbot.gpr.chain.velocity) is the weighted median of votes, each the velocity at
which a hyperbola migrated as a point diffractor focuses best. A cylinder of radius R whose top lies at
depth d has the apex curvature of a point at d + R, so a point focus matches it where v'·d' = v·(d + R)
with the apex time held (d'/v' = d/v): v' = v·√(1 + R/d). This prints every voter's vote beside that
prediction (from the truth's nearest target) and the line's estimate. It reads the dev half by default;
run it on the test half only to report, never to tune.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from gprbot.gpr.chain import velocity as chain_velocity
from gprbot.gpr.chain.candidates import apex_candidates
from gprbot.gpr.chain.prepare import prepare
from gprbot.gpr.chain.reflectors import fit_reflectors
from validation.cases import fdtd_cases

NEAR_M = 0.05  # a voter this close along the line to a truth target, and
NEAR_DEPTH_M = 0.04  # its apex time this close to the target's top at the true velocity, is taken as its hyperbola


def predicted_vote(v: float, top_m: float, radius_m: float) -> float:
    """The point-focus velocity of a cylinder's hyperbola: v·√(1 + R/d)."""
    return v * math.sqrt(1.0 + radius_m / max(top_m, 1e-3))


def main() -> None:
    """Print per scene and voter the vote, the cylinder's predicted vote and the line's estimate."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--half", default="fdtd-dev", choices=["fdtd-dev", "fdtd-test"])
    args = parser.parse_args()
    measured, predicted = [], []
    for case in (c for c in fdtd_cases() if c.group == args.half):
        bscan, gpr = case.load()
        prep = prepare(bscan, gpr)
        reflectors = fit_reflectors(prep, apex_candidates(prep))
        estimate = chain_velocity.estimate_velocity(prep, reflectors)
        v_true = float(case.velocity or math.nan)
        said = f"{100.0 * (estimate.v / v_true - 1.0):+.1f} %" if estimate else "not estimated"
        print(f"{case.name}: true {v_true:.4f} m/ns, line estimate {said}")
        for r in chain_velocity.voters(prep, reflectors):
            got = chain_velocity.vote(prep, r)
            x = float(prep.x_m[r.candidate.column])
            depth = 0.5 * v_true * r.candidate.t_ns  # the apex at the true velocity (air legs included: a bound)
            near = [t for t in case.targets if t.depth_m is not None and abs(t.x_m - x) <= NEAR_M
                    and abs(depth - (t.depth_m - (t.radius_m or 0.0))) <= NEAR_DEPTH_M]
            target = min(near, key=lambda t: abs(t.x_m - x)) if near else None
            text = f"  x {x:.3f} m, apex {r.candidate.t_ns:.2f} ns: "
            text += f"vote {100.0 * (got[0] / v_true - 1.0):+.0f} %" if got else "no vote"
            if target is not None and target.depth_m is not None:
                radius = target.radius_m or 0.0
                top = target.depth_m - radius
                expect = predicted_vote(v_true, top, radius)
                text += (f"; on a {target.kind} R {100 * radius:.1f} cm, top {100 * top:.1f} cm: "
                         f"cylinder predicts {100.0 * (expect / v_true - 1.0):+.0f} %")
                if got:
                    measured.append(got[0] / v_true - 1.0)
                    predicted.append(expect / v_true - 1.0)
            print(text)
    if measured:
        m, p = np.array(measured), np.array(predicted)
        print(f"\n{len(m)} votes on a target: median |vote error| {100 * np.median(np.abs(m)):.1f} %, "
              f"median |vote - cylinder prediction| {100 * np.median(np.abs(m - p)):.1f} %, "
              f"correlation {np.corrcoef(m, p)[0, 1]:.2f}")


if __name__ == "__main__":
    main()
