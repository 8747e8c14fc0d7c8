"""From B-scans to a 3D model: preprocess → interpret → register → sparse cloud → completion.

This is the work the inference worker does; `gprbot demo`, `gprbot replay` and the daemon all call it,
so that a simulated run and a run on the robot go through the same code.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gprbot.config import Config, model_path
from gprbot.errors import InterpretationError, ModelError
from gprbot.gpr.bscan import BScan, CrossSection, Detection
from gprbot.gpr.chain.candidates import apex_candidates
from gprbot.gpr.chain.classify import ClassifiedDetection
from gprbot.gpr.chain.prepare import prepare
from gprbot.gpr.chain.reflectors import fit_reflectors
from gprbot.gpr.chain.run import SurveyHint, interpret
from gprbot.gpr.chain.velocity import estimate_velocity as chain_velocity
from gprbot.gpr.chain.velocity import weighted_median
from gprbot.gpr.interpret import estimate_velocity, interpret_bscan
from gprbot.gpr.preprocess import preprocess
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.gpr.velocity import NO_HYPERBOLA, CrossingHint, VelocityEstimate, nearest_hint
from gprbot.infer.confirm import confirmed_section
from gprbot.infer.gprnet import GprnetCompletion, gprnet_reconstruction
from gprbot.infer.known_tops import calibrate_survey
from gprbot.infer.migrationnet import MigrationNetInterpreter
from gprbot.infer.refine import FitRefinerModel, refined_reconstruction
from gprbot.reconstruct.completion import Reconstruction, geometric_completion
from gprbot.reconstruct.extension import Footprint, survey_footprint
from gprbot.reconstruct.register import SliceCloud, register_slice, resample_cloud
from gprbot.reconstruct.survey_result import LineResult, SurveyResult

log = logging.getLogger(__name__)
# A survey velocity whose 1-sigma exceeds this share of it is not a measurement: simulated surveys with ten or more
# hyperbolas give 0.2-1.2 %, one weak hyperbola gave 140 %.
UNCONSTRAINED = 0.1


class SurveyVelocity(NamedTuple):
    """The survey's velocity (m/ns), whether it was estimated from the hyperbolas, the pipes' crossing angles,
    how it was found, in words, and its stated 1-sigma (m/ns; NaN where none is stated)."""

    v: float
    estimated: bool
    hints: tuple[CrossingHint, ...]
    method: str
    sigma: float = math.nan


def estimate_words(estimate: VelocityEstimate) -> str:
    """How the survey's hyperbolas gave its velocity, in words, and a warning where they hardly constrain it."""
    n = estimate.n_targets
    words = (f"estimated from {n} hyperbola{'' if n == 1 else 's'} on the lines, ±{estimate.uncertainty:.4f} m/ns "
             f"(1 sigma: the fit's own ±{estimate.std:.4f} and what the pipes' unknown sizes allow)")
    if estimate.std <= UNCONSTRAINED * estimate.v:
        return words
    # One weak hyperbola's curve trades the velocity against the pipe's size (validation/README.md): a simulated
    # survey over a lone 1.4 cm pipe read 0.154 ± 0.216 m/ns against a true 0.099, and every line came out empty.
    log.warning("the survey velocity %.4f m/ns rests on %d hyperbola(s) that hardly constrain it (±%.4f m/ns): "
                "depths may be far off; set gpr.eps_r or gpr.known_tops", estimate.v, n, estimate.std)
    return (f"{words}: the hyperbolas hardly constrain it, so depths may be far off; set gpr.eps_r, or give a known "
            "cover (gpr.known_tops)")


def survey_velocity(processed: Mapping[int, BScan], cfg: Config) -> SurveyVelocity:
    """The survey's wave velocity (configured eps_r, else calibrated on known tops, else all hyperbolas) and the
    pipes' crossing angles."""
    try:
        estimate = estimate_velocity(list(processed.values()), cfg.gpr, cfg.interpretation)
    except InterpretationError:
        estimate = None
    hints = estimate.crossings if estimate is not None else ()
    if cfg.gpr.eps_r is not None:
        return SurveyVelocity(velocity_from_eps(cfg.gpr.eps_r), False, hints, "from the configured eps_r")
    # The survey's hyperbola fits may find none to use; the interpretation chain's migration focus often still
    # does (the FDTD dev half laid on survey lines: 5 of the 6 surveys refused for want of a velocity).
    if estimate is not None:
        found = SurveyVelocity(float(estimate.v), True, hints, estimate_words(estimate), estimate.uncertainty)
    else:
        try:
            found = SurveyVelocity(chain_survey_velocity(list(processed.values()), cfg), True, (),
                                   "estimated from the lines' diffractions (migration focus)")
        except InterpretationError:
            if not cfg.gpr.known_tops:
                raise
            found = None
    if cfg.gpr.known_tops:
        # The hyperbolas' velocity tells each known top's apex from its neighbours' (`calibrate.apex_near`).
        calibration = calibrate_survey(processed, cfg.gpr, cfg.gpr.known_tops, found.v if found else None)
        for note in calibration.notes:
            log.warning("known tops: %s", note)
        if calibration.v is not None:
            return SurveyVelocity(calibration.v, False, hints, f"{calibration.method}, ±{calibration.sigma:.4f} m/ns",
                                  calibration.sigma)
        log.warning("no known top could be used (above): the velocity is estimated from the hyperbolas")
    if found is None:
        raise InterpretationError(NO_HYPERBOLA)
    return found


def chain_survey_velocity(lines: Sequence[BScan], cfg: Config) -> float:
    """The velocity the lines' diffractions agree on: each line's chain estimate, their median weighted by 1/sigma²."""
    votes = []
    for b in lines:
        try:
            prep = prepare(b, cfg.gpr)
        except InterpretationError:  # a line too short or broken to read: the others still vote
            continue
        est = chain_velocity(prep, fit_reflectors(prep, apex_candidates(prep)))
        if est is not None and est.sigma > 0:
            votes.append((est.v, 1.0 / est.sigma**2))
    if not votes:
        raise InterpretationError(NO_HYPERBOLA)
    return weighted_median(np.array([v for v, _ in votes]), np.array([w for _, w in votes]))


@functools.lru_cache(maxsize=2)
def migrationnet_interpreter(
    configured_path: str, threads: int, models_dir: str | None = None
) -> MigrationNetInterpreter:
    """MigrationNet's session, loaded and warmed up once per process (the worker keeps it between lines)."""
    return MigrationNetInterpreter(model_path(configured_path, models_dir), threads=threads)


@functools.lru_cache(maxsize=2)
def gprnet_completion(configured_path: str, threads: int, models_dir: str | None = None) -> GprnetCompletion:
    """GPRNet's session, loaded and warmed up once per process."""
    return GprnetCompletion(model_path(configured_path, models_dir), threads, expect_name="gprnet")


def interpret_line(
    line: int, processed: BScan, cfg: Config, velocity: float, hints: Sequence[CrossingHint] = ()
) -> LineResult:
    """Interpret one preprocessed line (as configured) and register it in 3D."""
    section = line_section(processed, cfg, velocity, hints)
    if cfg.interpretation.method != "chain":  # the chain's section carries its own rebar rows
        section = checked_by_chain(line, section, processed, cfg, velocity)
    cols = processed.position_at(section.x_m)
    std = processed.position_std_m
    pose_std = float(np.sqrt(np.mean(np.square(std)))) if std is not None and std.size else 0.0
    return LineResult(line, processed, section, register_slice(line, section.mask, section.z_m, cols, pose_std))


def line_section(
    processed: BScan, cfg: Config, velocity: float, hints: Sequence[CrossingHint] = ()
) -> CrossSection:
    """One preprocessed line's cross-section (pipes only), by the configured interpreter."""
    if cfg.interpretation.method == "migrationnet":
        interpreter = migrationnet_interpreter(cfg.interpretation.migrationnet_model, cfg.reconstruction.model_threads,
                                              cfg.models_dir)
        return interpreter.interpret(processed, cfg.gpr, cfg.interpretation, velocity)
    if cfg.interpretation.method == "chain":
        try:
            sizer = migrationnet_sizer(processed, cfg)
        except ModelError as exc:  # the pipes still come, their radii unmeasured where the curves say nothing
            log.warning("interpretation.radius_from: migrationnet, but %s; radii from the hyperbolas only", exc)
            sizer = None
        return interpret(processed, cfg.gpr, velocity, depth_max_m=cfg.interpretation.depth_max_m,
                         hint_at=survey_hints(processed, hints), sizer=sizer).section
    return interpret_bscan(processed, cfg.gpr, cfg.interpretation, velocity, crossing_hints=hints)


def migrationnet_sizer(bscan: BScan, cfg: Config) -> Callable[[float], tuple[Detection, ...]] | None:
    """MigrationNet's pipe blobs on a line at a velocity, for the chain's radii (`chain.sizing`); None when
    `interpretation.radius_from` is "fit". The line may be raw or preprocessed: MigrationNet's depth section
    preprocesses it, and preprocessing skips the steps already done. A model that cannot be loaded raises
    its ModelError."""
    if cfg.interpretation.radius_from != "migrationnet":
        return None
    net = migrationnet_interpreter(cfg.interpretation.migrationnet_model, cfg.reconstruction.model_threads,
                                   cfg.models_dir)
    return lambda v: net.interpret(bscan, cfg.gpr, cfg.interpretation, v).detections


def survey_hints(processed: BScan, hints: Sequence[CrossingHint]) -> Callable[[float], SurveyHint]:
    """What the survey's linked apices say of a pipe whose apex lies at along-track x on this line: the nearest
    hint (`velocity.nearest_hint`: its crossing angle and held radius), else nothing (at right angles, own radius)."""
    def hint_at(x_m: float) -> SurveyHint:
        nearest = nearest_hint(hints, processed.position_at(np.array([x_m]))[0, :2])
        return SurveyHint() if nearest is None else SurveyHint(nearest.sin_cross, nearest.radius_m)
    return hint_at


def checked_by_chain(line: int, section: CrossSection, processed: BScan, cfg: Config, velocity: float) -> CrossSection:
    """A line's section with the chain's rebar rows added, and MigrationNet's pipes confirmed against the chain's
    detections (`gprbot.infer.confirm`): its echoes and the blobs on a bar leave the section and its mask."""
    found = chain_detections(processed, cfg, velocity)
    rebars = tuple(d for d in found if d.kind == "rebar")
    if cfg.interpretation.method == "migrationnet":
        section, dropped = confirmed_section(section, found, rebars)
        for d, why in dropped:
            log.info("line %d: MigrationNet's blob at x %.3f m, depth %.3f m dropped: %s", line, d.x_m, d.depth_m, why)
    return replace(section, rebars=tuple(Detection(d.x_m, d.depth_m, d.radius_m, d.confidence) for d in rebars))


def chain_detections(processed: BScan, cfg: Config, velocity: float) -> tuple[ClassifiedDetection, ...]:
    """The interpretation chain's pipes and rebars on a line at the survey's velocity (none if it cannot run)."""
    try:
        return interpret(processed, cfg.gpr, velocity, depth_max_m=cfg.interpretation.depth_max_m).detections
    except InterpretationError:
        return ()


@functools.lru_cache(maxsize=2)
def fit_refiner(configured_path: str, threads: int, models_dir: str | None = None) -> FitRefinerModel:
    """The FitRefiner's session, loaded and warmed up once per process."""
    return FitRefinerModel(model_path(configured_path, models_dir), threads)


def complete_slices(
    slices: Sequence[SliceCloud], sparse: NDArray[np.float64], cfg: Config, rng: np.random.Generator,
    footprint: Footprint | None = None,
) -> tuple[Reconstruction, dict[str, float]]:
    """The configured completion (reconstruction.completion) of the registered slices and their sparse cloud.

    The one dispatch on the completion's name: the worker and training.eval_end_to_end both call it, so a
    completion added here is what both run. Returns the reconstruction and the model's timings (seconds).
    `footprint` (survey_footprint of the lines' positions) is where the refined completion may continue pipes.
    """
    if cfg.reconstruction.completion in ("refined", "extended"):
        if footprint is None:
            raise InterpretationError(f"the {cfg.reconstruction.completion} completion needs the survey's footprint "
                                      "(the lines' positions)")
        if cfg.reconstruction.completion == "extended":  # the refiner's baseline: every pipe continued by rule
            return refined_reconstruction(slices, sparse, footprint, cfg.reconstruction, None, rng), {}
        refiner = fit_refiner(cfg.reconstruction.refiner_model, cfg.reconstruction.model_threads, cfg.models_dir)
        return refined_reconstruction(slices, sparse, footprint, cfg.reconstruction, refiner, rng), {
            "refiner": refiner.last_seconds}
    if cfg.reconstruction.completion == "gprnet":
        # GPRNet gives the dense cloud; the pipes (pipes.json) still come from the fit through the slices,
        # which needs to know which points came from which survey line.
        completion = gprnet_completion(cfg.reconstruction.gprnet_model, cfg.reconstruction.model_threads,
                                       cfg.models_dir)
        return gprnet_reconstruction(slices, sparse, cfg.reconstruction, completion, rng), {
            "gprnet": completion.last_seconds}
    return geometric_completion(slices, cfg.reconstruction, rng), {}


def survey_steps(n_lines: int) -> int:
    """How many times reconstruct_survey calls on_step: preprocess, velocity, each line, completion."""
    return n_lines + 3


def _none_left(skipped: Mapping[int, str]) -> InterpretationError:
    """The error of a survey none of whose lines could be interpreted, with each line's reason."""
    return InterpretationError("no line of the survey could be interpreted: "
                               + "; ".join(f"line {k}: {why}" for k, why in sorted(skipped.items())))


def reconstruct_survey(bscans: Mapping[int, BScan], cfg: Config, rng: np.random.Generator,
                       on_step: Callable[[str], None] | None = None) -> SurveyResult:
    """Interpret every line of a survey and complete the registered slices into pipes.

    A line that cannot be interpreted (too short, flat traces) is left out and said so (`skipped_lines`):
    one line cut short must not cost the survey its other lines. InterpretationError when none is left.
    on_step(what) is called after each step (for a progress bar; survey_steps(n) steps in all).
    """
    step = on_step or (lambda _: None)
    timings: dict[str, float] = {}
    skipped: dict[int, str] = {}
    t0 = time.perf_counter()
    processed = {}
    for line, b in sorted(bscans.items()):
        try:
            processed[line] = preprocess(b, cfg.gpr)
        except InterpretationError as exc:
            skipped[line] = str(exc)
    if not processed:
        raise _none_left(skipped)
    timings["preprocess"] = time.perf_counter() - t0
    step("preprocessed")

    t0 = time.perf_counter()
    found = survey_velocity(processed, cfg)
    velocity, estimated, hints, velocity_method = found.v, found.estimated, found.hints, found.method
    timings["velocity"] = time.perf_counter() - t0
    step("velocity")

    t0 = time.perf_counter()
    interpreted = []
    for line, b in processed.items():
        try:
            interpreted.append(interpret_line(line, b, cfg, velocity, hints))
        except InterpretationError as exc:
            skipped[line] = str(exc)
        step(f"line {line}")
    if not interpreted:
        raise _none_left(skipped)
    for line, why in sorted(skipped.items()):
        log.warning("line %d left out of the survey: %s", line, why)
    lines = tuple(interpreted)
    # Each line was interpreted AT the survey's velocity, so its section would say "given"; the truth is
    # how the survey found it (all lines' hyperbolas, or the configured eps_r).
    lines = tuple(replace(lr, section=replace(lr.section, velocity_estimated=estimated)) for lr in lines)
    timings["interpret"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    slices = [lr.slice for lr in lines]
    points = np.concatenate([s.points for s in slices]) if slices else np.zeros((0, 3))
    sparse = resample_cloud(points, cfg.reconstruction.sparse_points, rng) if len(points) else points
    footprint = survey_footprint({line: b.positions for line, b in processed.items()}) if processed else None
    reconstruction, completion_timings = complete_slices(slices, sparse, cfg, rng, footprint)
    timings |= completion_timings
    timings["reconstruct"] = time.perf_counter() - t0
    step("completion")
    return SurveyResult(lines, velocity, estimated, sparse, reconstruction, timings, dict(sorted(skipped.items())),
                        velocity_method)
