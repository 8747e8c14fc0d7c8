"""`python -m validation.hyperbola_signatures dev|test`: how much radius and velocity a hyperbola can show.

A curve fit measures a pipe's radius from how a cylinder's two-way times depart from a point diffractor's,
and the velocity from how they change with it. For each FDTD target this takes the refracted-ray times of
the truth (each leg refracted towards the centre, less R: with refraction the reflection point lies on the
ray aimed at the centre, within 5 ps of a brute-force Fermat minimum, validation/README.md) and asks how
far the nearest curve of another kind stays from them, as the largest misfit in periods over the picks'
aperture (and within 35°):

- radius signature: the best point curve (free x and top) against the true cylinder;
- velocity signature: the best curve at the velocity 5 % off (free x and top, the radius held at the
  truth, or free too) against the truth.

Each is computed with refracted rays at the scene's antenna height, and with straight rays (a
ground-coupled antenna) as the other bound. Where a signature is a few hundredths of a period it is
smaller than the differences between any ray model and the data (0.05-0.3 periods on the dev half's
flanks), and no curve fit can measure that quantity; the top depth, which the curves share, stays measured.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from gprbot.gpr.chain.geometry import leg_time
from gprbot.gpr.chain.picks import PICK_APERTURE_DEG
from gprbot.gpr.chain.prepare import prepare
from validation.cases import fdtd_cases

SAMPLES = 81
VELOCITY_OFF = 0.05


def centre_ray_time(x: np.ndarray, x0: float, centre_m: float, radius_m: float, v: float, height_m: float,
                    offset_m: float) -> np.ndarray:
    """Two-way time to a cylinder: Tx and Rx legs refracted towards its centre, each less the radius."""
    depth = np.full_like(x, centre_m)
    legs = leg_time(height_m, x - 0.5 * offset_m - x0, depth, v) + leg_time(height_m, x + 0.5 * offset_m - x0, depth, v)
    return np.asarray(legs - 2.0 * radius_m / v)


@dataclass(frozen=True)
class Geometry:
    """A target and the antenna it is seen with."""

    x0: float
    centre_m: float
    radius_m: float
    v: float
    height_m: float
    offset_m: float
    period_ns: float

    def grid(self, aperture_deg: float) -> np.ndarray:
        """Midpoints over the aperture (in the ground) around the target."""
        reach = (self.centre_m - self.radius_m) * math.tan(math.radians(aperture_deg))
        return self.x0 + np.linspace(-reach, reach, SAMPLES)

    def times(self, x: np.ndarray, x0: float, top: float, radius: float, v: float) -> np.ndarray:
        """Two-way times of a cylinder with its top at `top`."""
        return centre_ray_time(x, x0, top + radius, radius, v, self.height_m, self.offset_m)


def _least_misfit(g: Geometry, x: np.ndarray, curve: Callable[[np.ndarray], np.ndarray], start: list[float],
                  lo: list[float], hi: list[float]) -> tuple[float, np.ndarray]:
    """(largest misfit in periods, parameters) of the best-fitting curve of a family against the truth."""
    truth = g.times(x, g.x0, g.centre_m - g.radius_m, g.radius_m, g.v)
    fit = least_squares(lambda q: curve(q) - truth, start, bounds=(lo, hi))
    return float(np.max(np.abs(fit.fun))) / g.period_ns, np.asarray(fit.x)


def radius_signature(g: Geometry, aperture_deg: float = PICK_APERTURE_DEG) -> tuple[float, float]:
    """(largest misfit in periods, top depth) of the point curve that best fits the cylinder's times."""
    x, top = g.grid(aperture_deg), g.centre_m - g.radius_m
    misfit, q = _least_misfit(g, x, lambda q: g.times(x, q[0], q[1], 0.0, g.v), [g.x0, top],
                              [g.x0 - 0.05, 1e-3], [g.x0 + 0.05, 5.0])
    return misfit, float(q[1])


def velocity_signature(g: Geometry, radius_known: bool, aperture_deg: float = PICK_APERTURE_DEG) -> float:
    """Least misfit (periods) of curves at the velocity VELOCITY_OFF fast or slow, radius held or free."""
    x, top = g.grid(aperture_deg), g.centre_m - g.radius_m
    out = math.inf
    for v in (g.v * (1.0 + VELOCITY_OFF), g.v * (1.0 - VELOCITY_OFF)):
        if radius_known:
            misfit, _ = _least_misfit(g, x, lambda q, v=v: g.times(x, q[0], q[1], g.radius_m, v), [g.x0, top],
                                      [g.x0 - 0.05, 1e-3], [g.x0 + 0.05, 5.0])
        else:
            misfit, _ = _least_misfit(g, x, lambda q, v=v: g.times(x, q[0], q[1], q[2], v), [g.x0, top, g.radius_m],
                                      [g.x0 - 0.05, 1e-3, 0.0], [g.x0 + 0.05, 5.0, 0.3])
        out = min(out, misfit)
    return out


@dataclass(frozen=True)
class Signature:
    """One target's signatures (periods) with refracted rays at its height and with straight rays."""

    scene: str
    kind: str
    radius_m: float
    top_m: float
    height_m: float
    frequency_mhz: float
    radius_35: float
    radius_60: float
    straight_radius_35: float
    straight_radius_60: float
    velocity_60: float  # 5 % off, radius held at the truth
    straight_velocity_60: float
    straight_velocity_free_r_60: float  # 5 % off, radius free too
    point_top_m: float


def signatures(half: str) -> list[Signature]:
    """Every target of the FDTD half (pipes, then one bar per rebar row depth)."""
    out = []
    for case in fdtd_cases():
        if case.group != f"fdtd-{half}" or case.velocity is None:
            continue
        bscan, gpr = case.load()
        prep = prepare(bscan, gpr)
        for t in case.targets:
            if t.depth_m is None or t.radius_m is None:
                continue
            g = Geometry(t.x_m, t.depth_m, t.radius_m, case.velocity, prep.antenna_height_m, prep.tx_rx_offset_m,
                         prep.period_ns)
            s = Geometry(t.x_m, t.depth_m, t.radius_m, case.velocity, 0.0, prep.tx_rx_offset_m, prep.period_ns)
            r60, point_top = radius_signature(g)
            out.append(Signature(case.name, t.kind, t.radius_m, t.depth_m - t.radius_m, prep.antenna_height_m,
                                 prep.frequency_mhz, radius_signature(g, 35.0)[0], r60, radius_signature(s, 35.0)[0],
                                 radius_signature(s)[0], velocity_signature(g, True), velocity_signature(s, True),
                                 velocity_signature(s, False), point_top))
    return out


def main(argv: list[str] | None = None) -> int:
    """Print each target's signatures and their medians."""
    parser = argparse.ArgumentParser(prog="python -m validation.hyperbola_signatures", description=__doc__)
    parser.add_argument("half", choices=["dev", "test"])
    args = parser.parse_args(argv)
    rows = signatures(args.half)
    cols = [("radius, refracted ≤35°", "radius_35"), ("radius, refracted ≤60°", "radius_60"),
            ("radius, straight ≤35°", "straight_radius_35"), ("radius, straight ≤60°", "straight_radius_60"),
            ("v ±5 %, R known, refracted ≤60°", "velocity_60"), ("v ±5 %, R known, straight ≤60°",
                                                                "straight_velocity_60"),
            ("v ±5 %, R free, straight ≤60°", "straight_velocity_free_r_60")]
    print("| scene | kind | radius cm | top cm | antenna height cm | " + " | ".join(c for c, _ in cols) + " |")
    print("|" + "---|" * (5 + len(cols)))
    for r in rows:
        print(f"| {r.scene} | {r.kind} | {100 * r.radius_m:.1f} | {100 * r.top_m:.1f} | {100 * r.height_m:.1f} | "
              + " | ".join(f"{getattr(r, a):.3f}" for _, a in cols) + " |")
    pipes = [r for r in rows if r.kind == "pipe"]
    print(f"\n{len(pipes)} pipes; signature in periods, median (how many under 0.05 and 0.1 period):")
    for label, attr in cols:
        p = np.array([getattr(r, attr) for r in pipes])
        print(f"- {label}: {np.median(p):.3f} ({(p < 0.05).sum()} and {(p < 0.1).sum()} of {len(p)})")
    tops = np.array([abs(r.point_top_m - r.top_m) for r in pipes])
    print(f"- the best point curve's top against the true top (refracted, ≤60°): largest {1000 * tops.max():.1f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
