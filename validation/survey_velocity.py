"""`python -m validation.survey_velocity`: the survey's velocity estimate per survey, against the truth.

The product's own estimate (`gprbot.infer.pipeline.survey_velocity`: the hyperbola fit of every line,
wide or held, else the chain's per-line votes), on the surveys `training.eval_end_to_end` runs: the FDTD
dev or test half laid on survey lines, or the first N simulated test surveys. Prints each survey's
error and the median |error| and the count within 5 %; `--wide-only` turns the held fit off
(`FLANKS_AGREE` = ∞), the estimate before 80bb197. `--known-top`: the velocity calibrated instead on the true
top of the survey's first pipe where it crosses the middle line (`gpr.known_tops`, gprbot/infer/known_tops.py),
as an inspector's one cover-meter reading would give it; surveys without a pipe are left out.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import time

import numpy as np

import gprbot.gpr.velocity as velocity
from gprbot.config import load_config
from gprbot.errors import GprbotError
from gprbot.gpr.preprocess import preprocess
from gprbot.infer.pipeline import survey_velocity
from training.e2e_surveys import Survey, survey_makers


def first_top(survey: Survey) -> tuple[float, float, float]:
    """(x, y, depth of the top) of the survey's first pipe where it crosses the middle line (site frame, m)."""
    pipe = survey.truth.pipes[0]
    lines = sorted(survey.bscans)
    positions = survey.bscans[lines[len(lines) // 2]].positions
    y = float(np.median(positions[:, 1]))
    a, b = pipe.points[0], pipe.points[-1]
    s = (y - a[1]) / (b[1] - a[1]) if b[1] != a[1] else 0.0  # the axis runs across the lines
    x = float(a[0] + s * (b[0] - a[0]))
    return x, y, float(-(a[2] + s * (b[2] - a[2])) - pipe.radius_m)


def main() -> None:
    """Print each survey's velocity error and the summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", choices=("dev", "test", "sim"))
    parser.add_argument("--limit", type=int, default=30, help="sim: the first N test surveys")
    parser.add_argument("--wide-only", action="store_true", help="the wide fit alone (before 80bb197)")
    parser.add_argument("--known-top", action="store_true", help="calibrate on the first pipe's true top")
    args = parser.parse_args()
    if args.wide_only:
        velocity.FLANKS_AGREE = math.inf
    base = load_config()
    errors: list[float] = []
    sigmas: list[tuple[float, float]] = []  # (|error| in m/ns, the stated 1-sigma)
    source, half = ("sim", "test") if args.source == "sim" else ("fdtd", args.source)
    for make in survey_makers(source, base.gpr, args.limit, half):
        survey = make()
        cfg = dataclasses.replace(base, gpr=survey.gpr)
        if args.known_top:
            if not survey.truth.pipes:
                continue
            cfg = dataclasses.replace(cfg, gpr=dataclasses.replace(survey.gpr, known_tops=(first_top(survey),)))
        start = time.perf_counter()
        try:
            found = survey_velocity({line: preprocess(b, cfg.gpr) for line, b in survey.bscans.items()}, cfg)
        except GprbotError as exc:
            print(f"{survey.name:26s} {survey.case[:22]:22s} not estimated: {exc}")
            errors.append(math.inf)
            continue
        error = found.v / survey.true_velocity - 1.0
        errors.append(abs(error))
        if math.isfinite(found.sigma):  # the 1-sigma the product states, where it states one
            sigmas.append((abs(found.v - survey.true_velocity), found.sigma))
        print(f"{survey.name:26s} {survey.case[:22]:22s} {100 * error:+6.1f} %  ({time.perf_counter() - start:.1f} s)"
              f"  {found.method}", flush=True)
    within = sum(1 for e in errors if e <= 0.05)
    median = 100 * statistics.median(errors)
    held = sum(1 for off, sigma in sigmas if off <= 2.0 * sigma)
    print(f"{args.source}: median |error| {median:.1f} %, within 5 % {within} of {len(errors)}; the true velocity "
          f"within 2 stated sigmas on {held} of the {len(sigmas)} that state one")


if __name__ == "__main__":
    main()
