"""Classical interpretation of one B-scan: pipes as cylinders fitted to the picked hyperbolas.

For every hyperbola (see `velocity`), with the velocity fixed, a cylinder is fitted to the picks:
centre along-track x0, centre depth dc, radius R and the crossing angle's sine s (an oblique pipe
gives a wider hyperbola; with v known the far flanks separate s from R). An air-filled PVC pipe's
inner-bottom echo (opposite polarity, 4R/c later) biases the top pick when the two overlap; it is
modelled at the apex, the bias removed, and its delay gives R independently of the velocity.

The cross-section mask is the union of the fitted cross-sections — ellipses R/s wide and R high in
the vertical plane of the line — kept where the migrated image shows energy on the pipe's top.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from gprbot.config import GprConfig, InterpretationConfig
from gprbot.gpr.bscan import BScan, CrossSection, Detection, check_bscan, ricker
from gprbot.gpr.migration import depth_axis, envelope, migrate, resample_uniform
from gprbot.gpr.preprocess import dewow, preprocess
from gprbot.gpr.traveltime import C_M_PER_NS, velocity_from_eps
from gprbot.gpr.velocity import (
    DEFAULT_SIN_STD,
    MAX_RADIUS_M,
    MIN_SIN_CROSS,
    PICK_STD_NS,
    CrossingHint,
    HyperbolaPicks,
    LineData,
    VelocityEstimate,
    cylinder_times,
    depth_for_apex_time,
    estimate_velocity,
    hyperbolas_of_line,
    matched_filter,
    prepare_line,
    without_interference,
)

__all__ = [
    "CrossSection", "CrossingHint", "CylinderFit", "Detection", "SurveyInterpretation", "VelocityEstimate",
    "detect_pipes", "estimate_velocity", "fit_cylinder", "inner_echo", "interpret_bscan", "interpret_survey",
]

FloatArray = NDArray[np.float64]
_APEX_TRACES = 3  # traces either side of the apex stacked for the inner-echo analysis
_HINT_RADIUS_M = 0.06  # a crossing hint applies to a hyperbola whose apex lies this close


@dataclass(frozen=True)
class CylinderFit:
    """A pipe fitted to one hyperbola: centre (x0, dc), radius, crossing sine, RMS misfit (ns), picks used."""

    x0_m: float
    depth_m: float
    radius_m: float
    sin_cross: float
    rms_ns: float
    n_picks: int
    inner_echo: bool


def fit_cylinder(
    x_m: FloatArray, t_ns: FloatArray, v: float, gpr: GprConfig, *,
    sin_prior: tuple[float, float] = (1.0, DEFAULT_SIN_STD),
    radius_m: float | None = None,
) -> CylinderFit:
    """Least-squares cylinder (x0, dc, R, s) through picks at a known velocity, outliers rejected.

    `sin_prior` (mean, std) is a prior on the crossing sine s — from the neighbouring lines, or
    "about at right angles" — because on one line s trades off against R. With `radius_m` given the
    radius is held (it came from the inner echo). A robust fit from several starts, then picks off
    by more than 3σ after a redescending (Cauchy) fit — crossing flanks — are dropped and it is refitted.
    """
    apex = int(np.argmin(t_ns))
    z_top = depth_for_apex_time(float(t_ns[apex]), v, gpr)
    x_apex = float(x_m[apex])
    s_mean, s_std = sin_prior
    held = radius_m is not None
    lb = [x_apex - 0.2, 0.005, MIN_SIN_CROSS] + ([] if held else [0.0])
    ub = [x_apex + 0.2, 3.0, 1.0] + ([] if held else [MAX_RADIUS_M])
    keep = np.ones(len(x_m), dtype=bool)

    def radius_of(p: FloatArray) -> float:
        return float(radius_m) if radius_m is not None else float(p[3])

    def residual(p: FloatArray) -> FloatArray:
        times = cylinder_times(x_m[keep], p[0], p[1], radius_of(p), v, gpr, p[2]) - t_ns[keep]
        return np.append(times, PICK_STD_NS * (p[2] - s_mean) / s_std)

    best: optimize.OptimizeResult | None = None
    starts = sorted({min(1.0, s_mean), 0.75}) if s_std >= DEFAULT_SIN_STD else [min(1.0, s_mean)]
    for r0 in [float(radius_m)] if radius_m is not None else [0.01, 0.04]:
        for s0 in starts:
            p0 = [x_apex, z_top + r0, s0] + ([] if held else [r0])
            sol = optimize.least_squares(residual, np.clip(p0, lb, ub), bounds=(lb, ub), loss="soft_l1",
                                         f_scale=0.01, x_scale="jac")
            if best is None or sol.cost < best.cost:
                best = sol
    assert best is not None
    # A redescending loss lets crossing flanks go, then they are dropped for good.
    best = optimize.least_squares(residual, best.x, bounds=(lb, ub), loss="cauchy", f_scale=0.004, x_scale="jac")
    r = residual(best.x)[:-1]
    sigma = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    keep = np.abs(r) < max(3.0 * sigma, 0.008)
    if keep.sum() >= 5:
        best = optimize.least_squares(residual, best.x, bounds=(lb, ub), loss="soft_l1", f_scale=0.004,
                                      x_scale="jac")
    r = residual(best.x)[:-1]
    return CylinderFit(float(best.x[0]), float(best.x[1]), radius_of(best.x), float(best.x[2]),
                       math.sqrt(float(np.mean(r**2))), int(keep.sum()), held)


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


def _sin_prior(bscan: BScan, h: HyperbolaPicks, hints: Sequence[CrossingHint]) -> tuple[float, float]:
    """Prior on a hyperbola's crossing sine: the nearest crossing hint, else "about at right angles"."""
    xy = bscan.position_at(h.point_model[0])[:2]
    near = [(math.hypot(c.xy[0] - xy[0], c.xy[1] - xy[1]), c.sin_cross, c.sin_std) for c in hints]
    close = [n for n in near if n[0] < _HINT_RADIUS_M]
    if not close:
        return 1.0, DEFAULT_SIN_STD
    _, sin_cross, sin_std = min(close)
    return sin_cross, sin_std


def detect_pipes(
    bscan: BScan, line: LineData, v: float, gpr: GprConfig, cfg: InterpretationConfig,
    hints: Sequence[CrossingHint] = (),
) -> list[tuple[Detection, CylinderFit]]:
    """Pipes of one line at a known velocity: track hyperbolas, fit cylinders, score, drop rebar rows."""
    found: list[tuple[Detection, CylinderFit]] = []
    for h in without_interference(hyperbolas_of_line(line, v, gpr, cfg), gpr):
        prior = _sin_prior(bscan, h, hints)
        # Only an echo of the direct wave's polarity (lower permittivity: air) has a strong inner echo.
        echo = inner_echo(line, h) if h.polarity == line.direct_polarity else None
        if echo is not None:
            fit = fit_cylinder(h.x_m, h.t_ns + echo[0], v, gpr, sin_prior=prior, radius_m=echo[1] * C_M_PER_NS / 4.0)
        else:
            fit = fit_cylinder(h.x_m, h.t_ns, v, gpr, sin_prior=prior)
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
