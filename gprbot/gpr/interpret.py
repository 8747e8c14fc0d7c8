"""Classical interpretation of one B-scan: pipes as cylinders fitted to the picked hyperbolas.

For every hyperbola (see `hyperbola`), with the velocity fixed, a cylinder is fitted to the picks
(`cylinder`): centre along-track x0, centre depth dc and the crossing angle's sine s, with priors
from the neighbouring lines (`velocity.CrossingHint`). The radius R is held: an air-filled PVC pipe's
inner-bottom echo (opposite polarity, 4R/c later) gives it independently of the velocity — the echo
is modelled at the apex and its bias on the top pick removed, and when the inner echo is the
stronger one, tracked instead of the top, the top is found before it; any other pipe takes the
median radius of its hyperbolas on all lines (one line alone barely tells R from the depth).

The cross-section mask is the union of the fitted cross-sections — ellipses R/s wide and R high in
the vertical plane of the line — kept where the migrated image shows energy on the pipe's top.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from gprbot.config import GprConfig, InterpretationConfig
from gprbot.gpr.bscan import BScan, CrossSection, Detection, check_bscan
from gprbot.gpr.cylinder import DEFAULT_SIN_STD, MIN_SIN_CROSS, CylinderFit, fit_cylinder
from gprbot.gpr.hyperbola import MAX_RADIUS_M, HyperbolaPicks, hyperbolas_of_line, without_interference
from gprbot.gpr.line_model import LineData, matched_filter, prepare_line
from gprbot.gpr.migration import depth_axis, envelope, migrate, resample_uniform
from gprbot.gpr.preprocess import dewow, preprocess
from gprbot.gpr.traveltime import C_M_PER_NS, velocity_from_eps
from gprbot.gpr.velocity import (
    CrossingHint,
    VelocityEstimate,
    estimate_velocity,
    nearest_hint,
)
from gprbot.gpr.wavelet import ricker

__all__ = [
    "CrossSection", "CrossingHint", "CylinderFit", "Detection", "SurveyInterpretation", "VelocityEstimate",
    "detect_pipes", "estimate_velocity", "fit_cylinder", "inner_echo", "interpret_bscan", "interpret_survey",
]

FloatArray = NDArray[np.float64]
_APEX_TRACES = 3  # traces either side of the apex stacked for the inner-echo analysis
_MIN_INNER_RATIO = -3.0  # inner-bottom / top echo of an air-filled pipe: about −0.8 to −2


def _wavelet_response(line: LineData) -> tuple[FloatArray, FloatArray]:
    """A lone echo as it looks after dewow and the matched filter, peak 1: (lags, values) to interpolate."""
    f = 1000.0 / line.period_ns
    lags = np.arange(-4.0 * line.period_ns, 4.0 * line.period_ns + 1e-9, line.dt_ns)
    pulse = dewow(ricker(lags, f)[None, :], line.dt_ns, f)
    response = matched_filter(np.asarray(pulse, dtype=np.float64), line.dt_ns, f)[0]
    return lags, response / response.max()


def inner_echo(line: LineData, h: HyperbolaPicks) -> tuple[float, float, float] | None:
    """(top-time correction, inner delay, amplitude ratio) of a pipe's inner-bottom echo at the apex.

    The traces around the apex, aligned on their picks and stacked, are fitted with one wavelet and
    with two (top + opposite-polarity inner echo Δ later); the two-echo model must explain most of
    what the single one leaves.
    """
    near = np.argsort(np.abs(h.x_m - h.apex_x_m))[: 2 * _APEX_TRACES + 1]
    dx = float(line.x_m[1] - line.x_m[0])
    tau = np.arange(-1.0 * line.period_ns, line.period_ns + 4.0 * MAX_RADIUS_M / C_M_PER_NS, line.dt_ns)
    stack = np.zeros_like(tau)
    for k in near:
        col = round((float(h.x_m[k]) - float(line.x_m[0])) / dx)
        samples = (h.t_ns[k] + tau + line.t0_ns) / line.dt_ns
        stack += np.interp(samples, np.arange(line.data.shape[1]), line.data[col], left=0.0, right=0.0)
    stack *= h.polarity / len(near)
    energy = float(stack @ stack)
    if energy <= 0.0:
        return None
    lags, response = _wavelet_response(line)
    shifts = np.arange(-0.3 * line.period_ns, 0.3 * line.period_ns, line.dt_ns / 2.0)
    delays = np.arange(0.25 * line.period_ns, 4.0 * MAX_RADIUS_M / C_M_PER_NS, line.dt_ns)
    # All shifted wavelets at once: W[k] = response(tau - shift_k); then every (shift, delay) pair.
    offsets = np.concatenate([shifts, (shifts[:, None] + delays[None, :]).ravel()])
    waves = np.interp(tau[None, :] - offsets[:, None], lags, response, left=0.0, right=0.0)
    top = waves[: len(shifts)]
    norms = np.einsum("ij,ij->i", top, top)
    single = float(energy - np.max((top @ stack) ** 2 / norms))
    inner = waves[len(shifts) :].reshape(len(shifts), len(delays), -1)
    g11 = norms[:, None]
    g12 = np.einsum("ik,ijk->ij", top, inner)
    g22 = np.einsum("ijk,ijk->ij", inner, inner)
    b1 = (top @ stack)[:, None]
    b2 = inner @ stack
    det = g11 * g22 - g12 * g12
    a1 = (g22 * b1 - g12 * b2) / det
    a2 = (g11 * b2 - g12 * b1) / det
    cost = np.where((a1 > 0) & (a2 < -0.25 * a1), energy - (a1 * b1 + a2 * b2), np.inf)
    i, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
    ratio = float(a2[i, j] / a1[i, j]) if a1[i, j] > 0 else 0.0
    best = (float(cost[i, j]), float(shifts[i]), float(delays[j]), ratio)
    if best is None or best[0] > 0.3 * single or best[3] > -0.25:
        return None
    return best[1], best[2], best[3]


def top_before_inner(line: LineData, h: HyperbolaPicks) -> tuple[HyperbolaPicks, tuple[float, float, float]] | None:
    """When h is an air-filled pipe's inner-bottom echo (stronger than its top): the top's picks and echo.

    The inner echo has the opposite polarity to the direct wave; the top precedes it by Δ ≤ 4R/c with
    the direct wave's polarity. The delay where the apex traces, shifted by Δ, stack best is checked
    with `inner_echo` on the shifted picks; a top far weaker than the inner echo (a steel pipe's side
    lobe: ratio below −3) is not one.
    """
    if h.polarity == line.direct_polarity:
        return None
    near = np.argsort(np.abs(h.x_m - h.apex_x_m))[: 2 * _APEX_TRACES + 1]
    dx = float(line.x_m[1] - line.x_m[0])
    cols = np.round((h.x_m[near] - float(line.x_m[0])) / dx).astype(np.intp)
    delays = np.arange(0.25 * line.period_ns, 4.0 * MAX_RADIUS_M / C_M_PER_NS, line.dt_ns / 2.0)
    samples = (h.t_ns[near][None, :] - delays[:, None] + line.t0_ns) / line.dt_ns
    index = np.arange(line.data.shape[1])
    stack = np.array([
        np.mean([np.interp(samples[i, k], index, line.data[c]) for k, c in enumerate(cols)])
        for i in range(len(delays))
    ]) * line.direct_polarity
    best = int(np.argmax(stack))
    if stack[best] <= 4.0 * line.noise:
        return None
    delay = float(delays[best])
    top = replace(h, t_ns=h.t_ns - delay, apex_t_ns=h.apex_t_ns - delay, polarity=line.direct_polarity)
    echo = inner_echo(line, top)
    if echo is None or echo[2] < _MIN_INNER_RATIO:
        return None
    return top, echo


def _score(h: HyperbolaPicks, fit: CylinderFit, line: LineData) -> float:
    """Confidence in [0, 1]: apex signal-to-noise, number of picks, and how well the cylinder fits."""
    snr = abs(h.apex_amplitude) / line.noise
    misfit = fit.rms_ns / (0.05 * line.period_ns)
    return float((1.0 - math.exp(-snr / 10.0)) * min(1.0, fit.n_picks / 15.0) * math.exp(-misfit))


def _drop_rebar_rows(found: list[tuple[Detection, CylinderFit]]) -> list[tuple[Detection, CylinderFit]]:
    """Remove a rebar mesh: three or more thin bars at one depth, evenly spaced along the line."""
    thin = [i for i, (d, _) in enumerate(found) if d.radius_m < 0.015]
    drop: set[int] = set()
    for i in thin:
        row = sorted((j for j in thin if abs(found[j][0].depth_m - found[i][0].depth_m) < 0.015),
                     key=lambda j: found[j][0].x_m)
        if len(row) >= 3:
            gaps = np.diff([found[j][0].x_m for j in row])
            if float(np.max(np.abs(gaps - np.median(gaps)))) < 0.25 * float(np.median(gaps)):
                drop.update(row)
    return [f for k, f in enumerate(found) if k not in drop]


def _crossing_prior(bscan: BScan, h: HyperbolaPicks, hints: Sequence[CrossingHint]) -> CrossingHint:
    """Prior on a hyperbola's crossing angle: the nearest crossing hint, else "about at right angles"."""
    xy = bscan.position_at(h.point_model[0])[:2]
    hint = nearest_hint(hints, xy)
    return hint if hint is not None else CrossingHint((float(xy[0]), float(xy[1])), 1.0, DEFAULT_SIN_STD)


def detect_pipes(
    bscan: BScan, line: LineData, v: float, gpr: GprConfig, cfg: InterpretationConfig,
    hints: Sequence[CrossingHint] = (),
) -> list[tuple[Detection, CylinderFit]]:
    """Pipes of one line at a known velocity: track hyperbolas, fit cylinders, score, drop rebar rows."""
    found: list[tuple[Detection, CylinderFit]] = []
    for h in without_interference(hyperbolas_of_line(line, v, gpr, cfg), gpr):
        hint = _crossing_prior(bscan, h, hints)
        prior = (hint.sin_cross, hint.sin_std)
        lateral = np.interp(h.x_m, line.x_m, line.lateral_m)
        # Only an echo of the direct wave's polarity (lower permittivity: air) has a strong inner echo,
        # which may be the stronger of the two and the one that was tracked.
        echo = inner_echo(line, h) if h.polarity == line.direct_polarity else None
        below = top_before_inner(line, h)
        if below is not None:
            h, echo = below
        # The radius: from the inner echo's delay, else the pipe's from all lines that saw it.
        held = hint.radius_m if echo is None else echo[1] * C_M_PER_NS / 4.0
        times = h.t_ns if echo is None else h.t_ns + echo[0]
        fit = fit_cylinder(h.x_m, times, v, gpr, sin_prior=prior, radius_m=held, lateral_m=lateral,
                           cot_sign=hint.cot_sign)
        fit = replace(fit, inner_echo=echo is not None)
        if fit.radius_m > 0.95 * MAX_RADIUS_M or fit.depth_m - fit.radius_m > cfg.depth_max_m:
            continue  # a flat event (shadow, layer) or beyond the image
        detection = Detection(fit.x0_m, fit.depth_m, fit.radius_m, _score(h, fit, line))
        if detection.score >= cfg.min_score:
            found.append((detection, fit))
    return _drop_rebar_rows(found)


def _ellipse_mask(fit: CylinderFit, x_m: FloatArray, z_m: FloatArray) -> NDArray[np.bool_]:
    """The pipe's cross-section in the line's vertical plane: R/s wide, R high."""
    half_width = fit.radius_m / max(fit.sin_cross, MIN_SIN_CROSS)
    u = (x_m[None, :] - fit.x0_m) / max(half_width, 1e-4)
    w = (z_m[:, None] - fit.depth_m) / max(fit.radius_m, 1e-4)
    return np.asarray(u * u + w * w <= 1.0)


def _top_supported(
    fit: CylinderFit, env: NDArray[np.floating], x_m: FloatArray, z_m: FloatArray, threshold: float
) -> bool:
    """Whether the migrated envelope around the pipe's top reaches `threshold` of its local maximum."""
    half_width = fit.radius_m / max(fit.sin_cross, MIN_SIN_CROSS) + 0.02
    cols = np.abs(x_m - fit.x0_m) <= half_width
    band = (z_m >= fit.depth_m - 2.0 * fit.radius_m - 0.03) & (z_m <= fit.depth_m + 2.0 * fit.radius_m + 0.03)
    top = np.abs(z_m - (fit.depth_m - fit.radius_m)) <= 0.02
    if not cols.any() or not top.any():
        return False
    local = float(env[np.ix_(band, cols)].max())
    return local > 0.0 and float(env[np.ix_(top, cols)].max()) >= threshold * local


def resolve_velocity(
    bscan: BScan, gpr: GprConfig, cfg: InterpretationConfig, velocity_m_per_ns: float | None
) -> tuple[float, bool]:
    """The velocity to use: given, from the configured eps_r, or estimated from this B-scan alone."""
    if velocity_m_per_ns is not None:
        return float(velocity_m_per_ns), False
    if gpr.eps_r is not None:
        return velocity_from_eps(gpr.eps_r), False
    return estimate_velocity([bscan], gpr, cfg).v, True


def interpret_bscan(
    bscan: BScan, gpr: GprConfig, cfg: InterpretationConfig, velocity_m_per_ns: float | None = None,
    *, crossing_hints: Sequence[CrossingHint] = (),
) -> CrossSection:
    """One B-scan → migrated image, pipe detections and the filled cross-section mask.

    `crossing_hints` (from `estimate_velocity(...).crossings`) give the crossing angle of oblique
    pipes; without them a pipe is assumed to cross roughly at right angles.
    """
    check_bscan(bscan)
    v, estimated = resolve_velocity(bscan, gpr, cfg, velocity_m_per_ns)
    line = prepare_line(bscan, gpr)
    found = detect_pipes(bscan, line, v, gpr, cfg, crossing_hints)
    pre = preprocess(replace(bscan, t0_ns=line.t0_ns), gpr)
    data, x = resample_uniform(pre, float(line.x_m[1] - line.x_m[0]))
    z = depth_axis(cfg.depth_max_m)
    image = migrate(data, x, pre.dt_ns, pre.t0_ns, z, v, method=cfg.migration,
                    antenna_height_m=gpr.antenna_height_m, tx_rx_offset_m=gpr.tx_rx_offset_m,
                    aperture_deg=cfg.aperture_deg)
    env = envelope(image)
    mask = np.zeros((len(z), len(x)), dtype=bool)
    detections = []
    for detection, fit in sorted(found, key=lambda f: f[0].x_m):
        if _top_supported(fit, env, x, z, cfg.mask_threshold):
            mask |= _ellipse_mask(fit, x, z)
        detections.append(detection)
    return CrossSection(mask, x, z, image.astype(np.float32), tuple(detections), v, estimated)


@dataclass(frozen=True)
class SurveyInterpretation:
    """All lines of a survey interpreted with one velocity and the crossing angles linked across lines."""

    velocity: VelocityEstimate | None
    sections: tuple[CrossSection, ...]


def interpret_survey(bscans: Sequence[BScan], gpr: GprConfig, cfg: InterpretationConfig) -> SurveyInterpretation:
    """Estimate the velocity from all lines (unless eps_r is configured), then interpret every line."""
    estimate = estimate_velocity(bscans, gpr, cfg)
    if gpr.eps_r is not None:
        v, estimated = velocity_from_eps(gpr.eps_r), False
    else:
        v, estimated = estimate.v, True
    sections = tuple(
        replace(interpret_bscan(b, gpr, cfg, v, crossing_hints=estimate.crossings), velocity_estimated=estimated)
        for b in bscans
    )
    return SurveyInterpretation(estimate, sections)
