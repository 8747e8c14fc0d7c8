"""The interpretation chain, one B-scan end to end: prepare → candidates → reflectors → velocity → classify →
spots of the migrated image → section; a line over a rebar mat is searched a second time below the mat, with
the mat's periodic response taken out (`mat`).

Each stage is a pure function with a typed result handed to the next (see the stage modules); this
module only strings them together and draws the cross-section. Nothing here depends on how the data
were made: wavelet and time zero come from the direct wave, the velocity from the hyperbolas.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from gprbot.config import GprConfig
from gprbot.gpr.bscan import BScan, CrossSection, Detection
from gprbot.gpr.chain.calibrate import KnownTop, calibrate
from gprbot.gpr.chain.candidates import ApexCandidate, apex_candidates
from gprbot.gpr.chain.classify import ClassifiedDetection, classify, relabel_rows
from gprbot.gpr.chain.mat import Mat, find_mat, without_mat
from gprbot.gpr.chain.prepare import PreparedBScan, prepare
from gprbot.gpr.chain.reflectors import SAME_TARGET_M, Reflector, fit_reflectors, refit_at_velocity
from gprbot.gpr.chain.sizing import sized
from gprbot.gpr.chain.spots import find_spots, spot_detections, without_echoes_of
from gprbot.gpr.chain.velocity import VelocityEstimate, Vote, estimate_velocity
from gprbot.gpr.migration import depth_axis, envelope, kirchhoff_migrate

FloatArray = NDArray[np.float64]
NOMINAL_VELOCITY = 0.1  # m/ns, concrete: used for depths only when nothing better is known, and said so
MAX_IMAGE_CELLS = 1_000_000  # the migrated image is decimated in depth beyond this (cost bound)
MIN_FOCUS = 0.3  # FDTD dev half and the real SS Mini line: true targets 0.6-3.4, false 0.12-0.27
FOCUS_WINDOW_M = 0.02
MASK_DZ_M = 0.0025  # the section's depth step (as the classical interpreter's): registration samples the mask
MIN_SINE = 0.3  # crossings steeper than ~17 degrees are not told apart from a pipe along the line


@dataclass(frozen=True)
class SurveyHint:
    """What a survey's other lines say about a pipe crossing this line near one apex."""

    sin_cross: float = 1.0  # sine of its crossing angle (1: at right angles)
    radius_m: float | None = None  # its radius from all the lines that saw it


@dataclass(frozen=True)
class Interpretation:
    """Everything the chain found on one B-scan, stage by stage, and the notes a user should read."""

    prepared: PreparedBScan
    candidates: tuple[ApexCandidate, ...]
    reflectors: tuple[Reflector, ...]
    velocity: float
    velocity_sigma: float
    velocity_source: Literal["given", "calibrated", "estimated", "fallback"]
    velocity_method: str
    detections: tuple[ClassifiedDetection, ...]
    section: CrossSection
    notes: tuple[str, ...]
    velocity_votes: tuple[Vote, ...] = ()  # each hyperbola's vote, where the velocity was estimated

    @property
    def pipes(self) -> tuple[ClassifiedDetection, ...]:
        """Detections classified as pipes."""
        return tuple(d for d in self.detections if d.kind == "pipe")

    @property
    def rebars(self) -> tuple[ClassifiedDetection, ...]:
        """Detections classified as rebar."""
        return tuple(d for d in self.detections if d.kind == "rebar")


def migrated(prep: PreparedBScan, v: float, depth_max_m: float) -> tuple[NDArray[np.float32], FloatArray]:
    """The Kirchhoff-migrated image (nz, nx) to depth_max_m, decimated in depth beyond MAX_IMAGE_CELLS."""
    # A sixteenth of the dominant wavelength resolves the focus; finer costs without showing more.
    dz = max(0.0025, prep.wavelength_m(v) / 16.0, depth_max_m * len(prep.x_m) / MAX_IMAGE_CELLS)
    z = depth_axis(depth_max_m, dz)
    image = kirchhoff_migrate(prep.data, prep.x_m, prep.dt_ns, prep.t0_ns, z, v,
                              antenna_height_m=prep.antenna_height_m, tx_rx_offset_m=prep.tx_rx_offset_m)
    return image, z


def across(d: ClassifiedDetection, v: float) -> ClassifiedDetection:
    """A detection fitted at an oblique pipe's along-track velocity v/sin, put at its true depth and radius."""
    if d.fit.v <= v * 1.001:  # fitted at the line's own velocity: at right angles
        return d
    s = v / d.fit.v
    fit = replace(d.fit, top_m=d.fit.top_m * s, radius_m=d.fit.radius_m * s, sigma_top_m=d.fit.sigma_top_m * s,
                  sigma_radius_m=d.fit.sigma_radius_m * s, v=v)
    return replace(d, depth_m=d.depth_m * s, radius_m=d.radius_m * s, radius_sigma_m=d.radius_sigma_m * s,
                   fit=fit, sin_cross=s)


def holding(d: ClassifiedDetection, radius: float | None) -> ClassifiedDetection:
    """A pipe given the radius the survey's lines agree on, where they have one.

    It is preferred even to a radius the line's own fit calls supported: one line's fit can be confidently
    wrong (a simulated oblique crossing: 14 cm, "supported", for a 2.7 cm pipe); the held radius is the median of
    the fits on every line that saw the pipe. Simulated surveys and the FDTD dev half: recall up, the
    diameters no worse.
    """
    if d.kind != "pipe" or radius is None:
        return d
    return replace(d, depth_m=d.fit.top_m + radius, radius_m=radius, radius_sigma_m=0.3 * radius,
                   radius_source="survey")


def focused(detections: tuple[ClassifiedDetection, ...], image: NDArray[np.float32], x_m: FloatArray,
            z_m: FloatArray, band_m: float) -> tuple[ClassifiedDetection, ...]:
    """The detections whose top the migrated image focuses (a V of crossing flanks or a flat bump fits a curve
    but migrates to nothing): the envelope there a fair share of the 99th percentile of the image's rows
    within `band_m` of its depth — its own depth, so that a weak deep pipe is not judged against the bright
    near-surface zone or a shallow mesh."""
    env = envelope(image)
    out = []
    for d in detections:
        cols, rows = np.abs(x_m - d.x_m) <= FOCUS_WINDOW_M, np.abs(z_m - d.fit.top_m) <= FOCUS_WINDOW_M
        band = np.abs(z_m - d.fit.top_m) <= max(band_m, FOCUS_WINDOW_M)
        local = float(env[np.ix_(rows, cols)].max()) if cols.any() and rows.any() else 0.0
        if band.any() and local >= MIN_FOCUS * float(np.percentile(env[band], 99.0)):
            out.append(d)
    return tuple(out)


def _section(prep: PreparedBScan, detections: tuple[ClassifiedDetection, ...], v: float, image: NDArray[np.float32],
             z: FloatArray, estimated: bool) -> CrossSection:
    """The filled pipe mask and the image on a MASK_DZ_M depth grid, with the detections.

    The migrated image may be coarser in depth (a sixteenth of a wavelength); the mask is what a survey's
    registration turns into points, so a pipe a few centimetres across must cover more than a few cells.
    """
    fine = depth_axis(float(z[-1]), MASK_DZ_M)
    if len(fine) > len(z):
        rows = np.interp(fine, z, np.arange(len(z)))
        lo = np.minimum(rows.astype(np.intp), len(z) - 2)
        w = (rows - lo)[:, None].astype(np.float32)
        image = (image[lo] * (1.0 - w) + image[lo + 1] * w).astype(np.float32)
        z = fine
    dz = float(z[1] - z[0])
    mask = np.zeros((len(z), len(prep.x_m)), dtype=bool)
    pipes, bars = [], []
    for d in detections:
        item = Detection(d.x_m, d.depth_m, d.radius_m, d.confidence, d.radius_source != "none",
                         d.radius_source == "migrationnet")
        if d.kind == "pipe":  # an oblique pipe's cross-section along the line: an ellipse R/sin wide
            r = max(d.radius_m, 0.5 * dz)
            mask |= ((prep.x_m[None, :] - d.x_m) * d.sin_cross) ** 2 + (z[:, None] - d.depth_m) ** 2 <= r * r
            pipes.append(item)
        else:
            bars.append(item)
    return CrossSection(mask, prep.x_m, z, image, tuple(pipes), v, estimated, rebars=tuple(bars))


def _detections(prep: PreparedBScan, reflectors: tuple[Reflector, ...], v: float,
                hint_at: Callable[[float], SurveyHint] | None, depth_m: float,
                ) -> tuple[tuple[ClassifiedDetection, ...], NDArray[np.float32], FloatArray]:
    """Classified hyperbolas and migrated spots of one prepared line at velocity v, and its migrated image."""
    # One line's own curve cannot tell an oblique crossing from a faster host (FDTD dev and the negative
    # geology line: taking fast curves as oblique added false pipes), so only the survey's hints say so.
    sines = [max(MIN_SINE, hint_at(r.free_fit.x0_m).sin_cross) if hint_at else 1.0 for r in reflectors]
    reflectors = refit_at_velocity(prep, reflectors, [v / s for s in sines])
    detections = tuple(across(d, v) for d in classify(prep, reflectors, v))
    image, z = migrated(prep, v, depth_m)
    detections = focused(detections, image, prep.x_m, z, prep.wavelength_m(v))
    spots = find_spots(prep, envelope(image), z, v)
    extra = spot_detections(prep, spots, detections, v)
    return relabel_rows(without_echoes_of(detections, extra, prep.wavelength_m(v)) + extra), image, z


def _same_target(d: ClassifiedDetection, found: Sequence[ClassifiedDetection]) -> bool:
    """Whether a detection's top lies within SAME_TARGET_M of one already found (x and depth of the top)."""
    return any(abs(d.x_m - f.x_m) <= SAME_TARGET_M and abs(d.fit.top_m - f.fit.top_m) <= SAME_TARGET_M for f in found)


@dataclass(frozen=True)
class BelowMat:
    """A line's rebar mat, the line with the mat's response taken out, and the hyperbolas there below the mat."""

    mat: Mat
    prep: PreparedBScan
    reflectors: tuple[Reflector, ...]
    from_ns: float  # what lies below the mat: apex times from here on (ns after transmit)


def below_mat(prep: PreparedBScan) -> BelowMat | None:
    """The line searched under its rebar mat, if it has one (`chain.mat`)."""
    mat = find_mat(prep)
    if mat is None:
        return None
    below = without_mat(prep, mat)
    # Only what lies a period below the mat's top is looked for there: at its depth the bars' residue (bars tied
    # by hand are not exactly periodic) would vote and be found again (SS Mini File____002).
    from_ns = mat.top_ns + prep.period_ns
    reflectors = tuple(r for r in fit_reflectors(below, apex_candidates(below)) if r.candidate.t_ns >= from_ns)
    return BelowMat(mat, below, reflectors, from_ns)


def hidden_by_mat(below: BelowMat, v: float, hint_at: Callable[[float], SurveyHint] | None, depth_m: float,
                  found: Sequence[ClassifiedDetection]) -> tuple[ClassifiedDetection, ...]:
    """What the mat hid: targets of the line searched with the mat taken out, below it, not found already."""
    hidden, _, _ = _detections(below.prep, below.reflectors, v, hint_at, depth_m)
    deeper = 0.5 * v * below.from_ns  # the same limit as a depth (the air gap and offset only make it shallower)
    # Within a period of either end the mat's response is estimated from one side only, and the mat's edge is not
    # periodic: what is left there is the mat's, not a target's (mesh_pipe_1600, velocity estimated).
    x = below.prep.x_m
    lo, hi = x[0] + below.mat.spacing_m, x[-1] - below.mat.spacing_m
    return tuple(d for d in hidden if d.fit.top_m >= deeper and lo <= d.x_m <= hi and not _same_target(d, found))


def interpret(
    bscan: BScan, gpr: GprConfig, velocity_m_per_ns: float | None = None, *,
    fallback_velocity_m_per_ns: float | None = None, depth_max_m: float | None = None,
    hint_at: Callable[[float], SurveyHint] | None = None, known_tops: Sequence[KnownTop] = (),
    sizer: Callable[[float], Sequence[Detection]] | None = None,
) -> Interpretation:
    """Interpret one B-scan: the velocity given, else calibrated on known tops (two at different depths fix
    time zero too), else estimated from its hyperbolas, else the fallback.

    `hint_at(x)` is what a survey's other lines say of a pipe whose apex lies at along-track x. An oblique
    pipe's hyperbola along the line is the right-angle one stretched by 1/sin: it is fitted at v/sin and
    its depth and radius are the fit's times sin. A pipe's radius is the survey's where it has one.

    `sizer(v)` segments the section migrated at v (MigrationNet: `gprbot.infer.pipeline.migrationnet_sizer`); a
    pipe whose curve does not measure its radius takes that of the blob at its top (`sizing`).
    """
    notes: list[str] = []
    prep = prepare(bscan, gpr)
    if prep.decimation > 1:
        notes.append(f"time sampling decimated {prep.decimation}x to dt {prep.dt_ns:.4f} ns "
                     f"({round(1000.0 / (prep.frequency_mhz * prep.dt_ns))} samples a period) to bound the cost")
    if prep.t0_method != "given":
        notes.append(f"time zero {prep.t0_ns:.2f} ns from the {prep.t0_method}")
    candidates = apex_candidates(prep)
    reflectors = fit_reflectors(prep, candidates)
    source: Literal["given", "calibrated", "estimated", "fallback"]
    calibrated = None
    if known_tops and velocity_m_per_ns is None:
        calibration = calibrate(prep, reflectors, known_tops)
        notes += calibration.notes
        calibrated = calibration.estimate
        if calibration.t0_shift_ns:  # two tops fixed time zero too: the line is read again from it
            prep = replace(prep, t0_ns=prep.t0_ns + calibration.t0_shift_ns, t0_method=f"{prep.t0_method}, moved "
                           f"{1000 * calibration.t0_shift_ns:+.0f} ps by the known tops")
            candidates = apex_candidates(prep)
            reflectors = fit_reflectors(prep, candidates)
    below = below_mat(prep)
    if below is not None:
        notes.append(f"a rebar mat every {100 * below.mat.spacing_m:.1f} cm: the line was also searched with its "
                     "periodic response taken out")
    votes: tuple[Vote, ...] = ()
    if velocity_m_per_ns is not None:
        v, sigma, source, how = float(velocity_m_per_ns), 0.0, "given", "given by the user"
    elif calibrated is not None:
        v, sigma, source, how = calibrated.v, calibrated.sigma, "calibrated", calibrated.method
    else:
        # Under a mat the bars' broken curves vote badly; the targets below it, clean of the mat, vote first.
        est: VelocityEstimate | None = ((estimate_velocity(below.prep, below.reflectors) if below is not None else None)
                                        or estimate_velocity(prep, reflectors))
        if est is not None:
            v, sigma, source, how, votes = est.v, est.uncertainty, "estimated", est.method, est.votes
            if est.shallow:
                notes.append("the velocity rests on shallow targets only (within 6 cm of the surface), where the "
                             "antenna's height and Tx-Rx offset govern the curves: check --height/--offset, "
                             "or pass --velocity if it is known")
        else:
            v = fallback_velocity_m_per_ns or NOMINAL_VELOCITY
            sigma, source = math.nan, "fallback"
            how = ("no diffraction hyperbola to measure it on; "
                   + (f"used {v:.4f} m/ns from the file's permittivity" if fallback_velocity_m_per_ns
                      else f"depths assume {v:.2f} m/ns (typical concrete): pass --velocity"))
            notes.append(f"velocity not estimated: {how}")
    depth = max(depth_max_m or 0.5 * v * (prep.data.shape[1] * prep.dt_ns - prep.t0_ns), 0.05)
    detections, image, z = _detections(prep, reflectors, v, hint_at, depth)
    if below is not None:
        # Each pass has told its rows from its pipes; across the two, pipes half a metre apart would make a "row".
        detections += hidden_by_mat(below, v, hint_at, depth, detections)
    if sizer is not None and any(d.kind == "pipe" and d.radius_source == "none" for d in detections):
        detections = sized(detections, sizer(v))
    if hint_at is not None:
        detections = tuple(holding(d, hint_at(d.x_m).radius_m) for d in detections)
    section = _section(prep, detections, v, image, z, source == "estimated")
    return Interpretation(prep, candidates, reflectors, v, sigma, source, how, detections, section, tuple(notes),
                          votes)
