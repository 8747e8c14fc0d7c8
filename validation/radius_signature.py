"""`python -m validation.radius_signature dev|test`: how much of a pipe's radius its hyperbola can show.

A curve fit measures a radius from how a cylinder's two-way times depart from a point diffractor's. For
each FDTD pipe this takes the refracted-ray times of the true cylinder (each leg the refracted leg to the
centre less R: with refraction the reflection point lies on the ray aimed at the centre, within 5 ps of a
brute-force Fermat minimum, validation/README.md), fits the best point curve (free x and top) to them over
the picks' aperture, and prints the largest misfit in periods: the radius signature. Where it is a few
hundredths of a period it is smaller than the differences between any ray model and the data (0.05-0.3
periods on the dev half's flanks), and no curve fit can tell the radius; the top depth, which both
curves share, stays measured.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from gprbot.gpr.chain.geometry import leg_time
from gprbot.gpr.chain.picks import PICK_APERTURE_DEG
from gprbot.gpr.chain.prepare import prepare
from validation.cases import fdtd_cases

SAMPLES = 81


@dataclass(frozen=True)
class Signature:
    """One pipe's radius signature: the scene, the pipe, the antenna and the misfit of the best point curve."""

    scene: str
    radius_m: float
    top_m: float
    height_m: float
    frequency_mhz: float
    periods: float  # largest |cylinder - best point curve| over the picks' aperture, in periods
    periods_35: float  # the same within 35 degrees, where the ray models fit the flanks best
    straight: float  # over the aperture with straight rays (a ground-coupled antenna: the upper bound)
    straight_35: float
    point_top_m: float


def centre_ray_time(x: np.ndarray, x0: float, centre_m: float, radius_m: float, v: float, height_m: float,
                    offset_m: float) -> np.ndarray:
    """Two-way time to a cylinder: Tx and Rx legs refracted towards its centre, each less the radius."""
    depth = np.full_like(x, centre_m)
    legs = leg_time(height_m, x - 0.5 * offset_m - x0, depth, v) + leg_time(height_m, x + 0.5 * offset_m - x0, depth, v)
    return np.asarray(legs - 2.0 * radius_m / v)


def signature(x0: float, centre_m: float, radius_m: float, v: float, height_m: float, offset_m: float,
              period_ns: float, aperture_deg: float = PICK_APERTURE_DEG) -> tuple[float, float]:
    """(largest misfit in periods, top depth) of the point curve that best fits a cylinder's times."""
    top = centre_m - radius_m
    reach = top * math.tan(math.radians(aperture_deg))
    x = x0 + np.linspace(-reach, reach, SAMPLES)
    truth = centre_ray_time(x, x0, centre_m, radius_m, v, height_m, offset_m)

    def misfit(q: np.ndarray) -> np.ndarray:
        return np.asarray(centre_ray_time(x, q[0], q[1], 0.0, v, height_m, offset_m) - truth)

    fit = least_squares(misfit, [x0, top], bounds=([x0 - 0.05, 1e-3], [x0 + 0.05, 5.0]))
    return float(np.max(np.abs(fit.fun))) / period_ns, float(fit.x[1])


def signatures(half: str) -> list[Signature]:
    """Every pipe of the FDTD half's radius signature."""
    out = []
    for case in fdtd_cases():
        if case.group != f"fdtd-{half}" or case.velocity is None:
            continue
        bscan, gpr = case.load()
        prep = prepare(bscan, gpr)
        for t in case.targets:
            if t.kind != "pipe" or t.depth_m is None or t.radius_m is None:
                continue
            geometry = (case.velocity, prep.antenna_height_m, prep.tx_rx_offset_m, prep.period_ns)
            periods, point_top = signature(t.x_m, t.depth_m, t.radius_m, *geometry)
            narrow, _ = signature(t.x_m, t.depth_m, t.radius_m, *geometry, aperture_deg=35.0)
            coupled = (case.velocity, 0.0, prep.tx_rx_offset_m, prep.period_ns)
            straight, _ = signature(t.x_m, t.depth_m, t.radius_m, *coupled)
            straight_35, _ = signature(t.x_m, t.depth_m, t.radius_m, *coupled, aperture_deg=35.0)
            out.append(Signature(case.name, t.radius_m, t.depth_m - t.radius_m, prep.antenna_height_m,
                                 prep.frequency_mhz, periods, narrow, straight, straight_35, point_top))
    return out


def main(argv: list[str] | None = None) -> int:
    """Print each pipe's radius signature and the share under 0.1 and 0.2 periods."""
    parser = argparse.ArgumentParser(prog="python -m validation.radius_signature", description=__doc__)
    parser.add_argument("half", choices=["dev", "test"])
    args = parser.parse_args(argv)
    rows = signatures(args.half)
    print("| scene | radius cm | top cm | antenna height cm | centre MHz (data) | refracted ≤60° | ≤35° "
          "| straight ≤60° | ≤35° | point top cm |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r.scene} | {100 * r.radius_m:.1f} | {100 * r.top_m:.1f} | {100 * r.height_m:.1f} | "
              f"{r.frequency_mhz:.0f} | {r.periods:.3f} | {r.periods_35:.3f} | {r.straight:.3f} | "
              f"{r.straight_35:.3f} | {100 * r.point_top_m:.1f} |")
    print(f"\n{len(rows)} pipes; radius signature in periods, median (under 0.1 period):")
    for label, values in (("refracted rays, within 60°", [r.periods for r in rows]),
                          ("refracted rays, within 35°", [r.periods_35 for r in rows]),
                          ("straight rays, within 60°", [r.straight for r in rows]),
                          ("straight rays, within 35°", [r.straight_35 for r in rows])):
        p = np.array(values)
        print(f"- {label}: {np.median(p):.3f} ({(p < 0.1).sum()} of {len(p)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
