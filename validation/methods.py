"""The interpretation methods the evaluation compares, each as `run(bscan, gpr, velocity) -> Outcome`.

- `chain`: the interpretation chain (gprbot.gpr.chain), the product's classical path;
- `legacy`: the previous classical interpreter (gprbot.gpr.interpret), kept for comparison;
- `migrationnet`: the shipped MigrationNet ONNX model on the migrated section as the product runs it: its pipes
  confirmed against the chain's detections, and the chain's rebars (needs a velocity: the chain's estimate is
  handed to it when none is given, and the table says so).
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np

from gprbot.config import GprConfig, InterpretationConfig
from gprbot.errors import GprbotError
from gprbot.gpr.bscan import BScan
from validation.scoring import Found


@dataclass(frozen=True)
class Outcome:
    """What a method found on one B-scan, the velocity it used, whether it estimated it, and its time."""

    found: tuple[Found, ...]
    velocity: float
    velocity_estimated: bool
    seconds: float
    note: str = ""
    velocity_sigma: float = math.nan  # the method's own 1-sigma of an estimated velocity (NaN: it states none)


LEGACY_MAX_LINE_M = 40.0

Method = Callable[[BScan, GprConfig, "float | None"], Outcome]


def run_chain(bscan: BScan, gpr: GprConfig, velocity: float | None,
              radius_from: Literal["migrationnet", "fit"] | None = None) -> Outcome:
    """The interpretation chain, its unmeasured radii from MigrationNet's mask or not as `radius_from` says
    (None: as the product's default, `InterpretationConfig.radius_from`)."""
    from gprbot.config import Config
    from gprbot.gpr.chain.run import interpret
    from gprbot.infer.pipeline import migrationnet_sizer

    interp = InterpretationConfig()
    cfg = replace(Config(), gpr=gpr, interpretation=replace(interp, radius_from=radius_from or interp.radius_from))
    start = time.perf_counter()
    sizer = migrationnet_sizer(bscan, cfg)
    result = interpret(bscan, gpr, velocity, sizer=sizer)
    seconds = time.perf_counter() - start
    found = tuple(Found(d.x_m, d.depth_m, d.radius_m, d.kind, d.radius_supported) for d in result.detections)
    return Outcome(found, result.velocity, result.velocity_source == "estimated", seconds, "; ".join(result.notes),
                   result.velocity_sigma)


def _interp_config(bscan: BScan, v: float) -> InterpretationConfig:
    """The legacy interpreter's settings with the depth range of the record."""
    window = bscan.data.shape[1] * bscan.dt_ns
    return replace(InterpretationConfig(), depth_max_m=max(0.1, 0.5 * v * window))


def run_legacy(bscan: BScan, gpr: GprConfig, velocity: float | None) -> Outcome:
    """The previous classical interpreter, as `gprbot interpret` ran it before the chain."""
    from gprbot.gpr.interpret import interpret_bscan
    from gprbot.gpr.preprocess import preprocess

    start = time.perf_counter()
    if float(np.ptp(bscan.along_track_m())) > LEGACY_MAX_LINE_M:
        # It resamples every line to a 1-5 cm grid and fits every hyperbola: minutes on a 100 m line.
        return Outcome((), math.nan, velocity is None, 0.0, f"not run: line longer than {LEGACY_MAX_LINE_M:g} m")
    try:
        processed = preprocess(bscan, gpr)
        section = interpret_bscan(processed, gpr, _interp_config(bscan, velocity or 0.12), velocity)
    except GprbotError as exc:
        return Outcome((), math.nan, velocity is None, time.perf_counter() - start, f"failed: {exc}")
    seconds = time.perf_counter() - start
    found = tuple(Found(d.x_m, d.depth_m, d.radius_m, "pipe", d.radius_supported) for d in section.detections)
    return Outcome(found, section.velocity_m_per_ns, section.velocity_estimated, seconds)


def run_migrationnet(bscan: BScan, gpr: GprConfig, velocity: float | None, model: str | None = None) -> Outcome:
    """MigrationNet (the shipped model, or the ONNX file `model`) as the product runs it: its pipes on the section at
    the given velocity, confirmed against the chain's detections there (`gprbot.infer.confirm`), and the chain's rebars.

    Without a velocity it uses the chain's estimate.
    """
    from gprbot.gpr.chain.run import interpret
    from gprbot.gpr.preprocess import preprocess
    from gprbot.infer.confirm import confirmed_section
    from gprbot.infer.pipeline import migrationnet_interpreter

    start = time.perf_counter()
    try:
        chain = interpret(bscan, gpr, velocity)
    except GprbotError as exc:
        return Outcome((), velocity or math.nan, False, time.perf_counter() - start, f"failed: {exc}")
    v, estimated = chain.velocity, chain.velocity_source == "estimated"
    note = "" if velocity is not None else "velocity from the chain"
    try:
        net = migrationnet_interpreter(model or InterpretationConfig().migrationnet_model, 2)
        section = net.interpret(preprocess(bscan, gpr), gpr, _interp_config(bscan, v), v)
    except GprbotError as exc:
        return Outcome((), v, estimated, time.perf_counter() - start, f"failed: {exc}")
    section, _ = confirmed_section(section, chain.detections, chain.rebars)
    seconds = time.perf_counter() - start
    found = tuple(Found(d.x_m, d.depth_m, d.radius_m, "pipe", d.radius_supported and not d.radius_from_mask)
                  for d in section.detections)
    found += tuple(Found(d.x_m, d.depth_m, d.radius_m, "rebar", d.radius_supported) for d in chain.rebars)
    return Outcome(found, v, estimated, seconds, note, chain.velocity_sigma)


def run_chain_mask_radius(bscan: BScan, gpr: GprConfig, velocity: float | None) -> Outcome:
    """The interpretation chain with the radii its curves do not measure from MigrationNet's pipe mask
    (`interpretation.radius_from: migrationnet`)."""
    return run_chain(bscan, gpr, velocity, "migrationnet")


METHODS: dict[str, Method] = {"chain": run_chain, "chain-mask-radius": run_chain_mask_radius, "legacy": run_legacy,
                              "migrationnet": run_migrationnet}


def methods_with_migrationnet(model: Path | str) -> dict[str, Method]:
    """METHODS with `migrationnet` running the ONNX file `model` instead of the shipped one (model selection)."""
    return {**METHODS, "migrationnet": functools.partial(run_migrationnet, model=str(model))}
