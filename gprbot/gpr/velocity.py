"""Hyperbola picking and survey-wide velocity estimation from the pipes' reflections.

Every pick is the main-lobe peak of a reflection (the same wavelet phase that defines time zero),
and every fit uses the exact refracted two-way time to the cylinder's specular point with the
antenna height and the Tx–Rx offset (`traveltime.two_way_time`): a straight-ray t² = t0² + 4x²/v²
fit that ignores them misjudges the velocity by 10–40 % on shallow pipes.

What separates the velocity from the pipes' radii: a hyperbola's apex time fixes the top of the pipe
(dc − R), its curvature fixes dc · v, and only the far flanks (4th-order moveout and the refraction
at the surface) separate v from R. So the velocity is one unknown shared by all hyperbolas of all
lines, each with its own centre and radius, fitted over a WIDE aperture (60° in the ground) — which
the refracted model allows where a straight-ray model would need ≤ 35°. With a 35° aperture the
same data give 2–5 % velocity errors and radii off by a factor of 2 (measured, see tests).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage, optimize
from scipy.sparse import lil_matrix

from gprbot.config import GprConfig, InterpretationConfig
from gprbot.errors import InterpretationError
from gprbot.gpr.bscan import BScan, check_bscan, grid_spacing_m, ricker
from gprbot.gpr.migration import depth_axis, diffraction_times, envelope, kirchhoff_migrate, resample_uniform
from gprbot.gpr.preprocess import (
    BACKGROUND,
    BACKGROUND_WINDOW_M,
    DEWOW,
    dewow,
    direct_wave_polarity,
    find_time_zero,
    recorded_direct_polarity,
    remove_background,
    remove_gain,
)
from gprbot.gpr.traveltime import C_M_PER_NS, two_way_time

FloatArray = NDArray[np.float64]
FloatLike = float | FloatArray

V_GUESS_M_PER_NS = 0.12  # concrete, eps_r 6.25: only a starting point for the picking
V_BOUNDS_M_PER_NS = (0.05, 0.25)
FIT_APERTURE_DEG = 60.0
MAX_RADIUS_M = 0.15
_PICK_WINDOW_PERIODS = 0.35  # < 0.39 T: the Ricker's side lobes never enter the window
_MAX_MISSES = 3
_MIN_FLANK_PICKS = 3
_MIN_FLANK_RISE_PERIODS = 0.25
_POINT_DEPTH_MAX_M = 3.0
_END_TRIM = 2
_MAX_JUMP_PERIODS = 0.06  # largest change of misfit between neighbouring picks
_MIN_PICKS = 7
_IN_LINE = np.array([1.0, 0.0])
_ANGLE_STD_RAD = 0.025
PICK_STD_NS = 0.005  # typical pick scatter: weighs a crossing-angle prior against the picks
DEFAULT_SIN_STD = 0.05  # no twin on the neighbouring lines: "roughly at right angles" (s = 0.95 is 72°)
MIN_SIN_CROSS = 0.34  # pipes crossing a line at under 20° do not make hyperbolas


@dataclass(frozen=True)
class CrossingHint:
    """Where a pipe crosses a survey line (its apex, site-frame x, y) and the sine of the crossing angle.

    Found by linking the apices of neighbouring lines; `interpret_bscan` uses it as a prior on the
    crossing angle, which a single line barely separates from the radius.
    """

    xy: tuple[float, float]
    sin_cross: float
    sin_std: float = 0.02


@dataclass(frozen=True)
class VelocityEstimate:
    """Survey-wide wave velocity v (m/ns), its standard deviation, how many hyperbolas gave it, crossings."""

    v: float
    std: float
    n_targets: int
    crossings: tuple[CrossingHint, ...] = ()


@dataclass(frozen=True)
class LineData:
    """A preprocessed line on a uniform along-track grid, ready for picking (matched-filtered, no gain)."""

    data: FloatArray  # (nx, ns)
    x_m: FloatArray
    dt_ns: float
    t0_ns: float
    noise: float  # robust standard deviation of the samples
    period_ns: float
    direct_polarity: float  # sign of the direct wave: echoes of this sign come from lower permittivity

    def time_of(self, sample: FloatArray | float) -> FloatArray:
        """Two-way time after transmit (ns) of a (fractional) sample index."""
        return np.asarray(np.asarray(sample) * self.dt_ns - self.t0_ns)


@dataclass(frozen=True)
class HyperbolaPicks:
    """Main-lobe picks of one reflection hyperbola: along-track x, time after transmit, amplitude.

    `point_model` is the point-diffractor fit (x0, depth, apparent velocity) that steered the picks.
    """

    x_m: FloatArray
    t_ns: FloatArray
    amplitude: FloatArray
    polarity: float
    apex_x_m: float
    apex_t_ns: float
    apex_amplitude: float
    point_model: tuple[float, float, float]


def prepare_line(bscan: BScan, gpr: GprConfig) -> LineData:
    """Dewow, time zero, uniform grid, median background removal, matched filter — and no gain.

    A B-scan that was already preprocessed has its gain undone (a gain ramp shifts peaks).
    """
    check_bscan(bscan)
    raw = remove_gain(bscan)
    dewowed = raw.data if DEWOW in raw.processing else dewow(raw.data, raw.dt_ns, gpr.centre_frequency_mhz)
    t0 = raw.t0_ns
    if not math.isfinite(t0):
        t0 = find_time_zero(dewowed, raw.dt_ns, gpr.tx_rx_offset_m, gpr.antenna_height_m)
    resampled, x = resample_uniform(replace(raw, data=dewowed), grid_spacing_m(raw.along_track_m()))
    window = BACKGROUND_WINDOW_M if float(x[-1] - x[0]) > BACKGROUND_WINDOW_M else None
    cleaned = remove_background(resampled, x, window_m=window, spacing_m=float(x[1] - x[0]))
    d = matched_filter(np.asarray(cleaned, dtype=np.float64), raw.dt_ns, gpr.centre_frequency_mhz)
    noise = float(1.4826 * np.median(np.abs(d - np.median(d)))) or float(np.std(d)) or 1e-12
    period = 1000.0 / gpr.centre_frequency_mhz
    # The direct wave's sign: recorded by preprocess before it removed the background, or read here.
    polarity = recorded_direct_polarity(raw.processing)
    if polarity is None:
        polarity = direct_wave_polarity(dewowed, raw.dt_ns) if BACKGROUND not in raw.processing else 1.0
    return LineData(d, x, raw.dt_ns, t0, noise, period, polarity)


def matched_filter(data: FloatArray, dt_ns: float, centre_frequency_mhz: float) -> FloatArray:
    """Correlate every trace with the Ricker wavelet: the peak times stay, the white noise drops ~4×.

    A peak picked on three raw samples sees the noise of three samples; after the matched filter it
    sees that of the whole wavelet. The Ricker is symmetric, so correlation moves no peak.
    """
    half = math.ceil(1.5 * 1000.0 / (centre_frequency_mhz * dt_ns))
    kernel = ricker(np.arange(-half, half + 1, dtype=np.float64) * dt_ns, centre_frequency_mhz)
    kernel /= float(np.sum(kernel**2))
    return np.asarray(ndimage.convolve1d(data, kernel, axis=1, mode="constant"))


def cylinder_times(
    x_m: FloatArray, x0: FloatLike, dc: FloatLike, radius: FloatLike, v: float, gpr: GprConfig,
    sin_cross: FloatLike = 1.0,
) -> FloatArray:
    """Two-way times along the line to a pipe crossing it at x0 (centre depth dc, radius, crossing angle).

    `sin_cross` is the sine of the angle between the pipe's axis and the line (1: at right angles).
    The pipe parameters broadcast against x_m (one pipe, or one pipe per pick). The reflection
    comes from the specular point: the point of the pipe's surface nearest to the ground point
    under the antenna (as `traveltime.cylinder_specular_point`).
    """
    x = np.asarray(x_m, dtype=np.float64)
    s = np.clip(np.asarray(sin_cross, dtype=np.float64), 1e-3, 1.0)
    cos = np.sqrt(1.0 - s * s)
    depth = np.asarray(dc, dtype=np.float64)
    dx = x - np.asarray(x0, dtype=np.float64)
    along_axis = dx * cos  # ground point minus centre, projected on the axis direction (cos, s, 0)
    gx, gy, gz = dx - along_axis * cos, -along_axis * s, depth  # from the nearest axis point to the ground point
    dist = np.maximum(np.sqrt(gx * gx + gy * gy + gz * gz), 1e-9)
    shrink = 1.0 - np.asarray(radius, dtype=np.float64) / dist
    point = np.stack(np.broadcast_arrays(x - gx * shrink, -gy * shrink, -gz * shrink), axis=-1)
    mid = np.stack([x, np.zeros_like(x)], axis=-1)
    return two_way_time(mid, point, v, gpr.antenna_height_m, gpr.tx_rx_offset_m, _IN_LINE)


def depth_for_apex_time(t_ns: float, v: float, gpr: GprConfig) -> float:
    """Depth of a point diffractor right below the antenna whose two-way time is t_ns."""
    z = np.linspace(0.0, max(0.05, v * t_ns), 400)
    times = diffraction_times(np.zeros(1), z, v, gpr.antenna_height_m, gpr.tx_rx_offset_m)[0]
    return float(np.interp(t_ns, times, z))


def find_apex_candidates(
    line: LineData, v: float, gpr: GprConfig, cfg: InterpretationConfig, *, snr: float = 4.0
) -> list[tuple[float, float, float]]:
    """Apices (x, t_after_transmit, strength) from peaks of the Kirchhoff-migrated envelope at velocity v.

    A peak must stand `snr` times above its depth row's median envelope (noise and clutter level)
    and above 3 % of the strongest peak; neighbouring peaks within a wavelength are merged.
    """
    z = depth_axis(cfg.depth_max_m, 0.0025)
    image = kirchhoff_migrate(
        line.data, line.x_m, line.dt_ns, line.t0_ns, z, v,
        antenna_height_m=gpr.antenna_height_m, tx_rx_offset_m=gpr.tx_rx_offset_m, aperture_deg=cfg.aperture_deg,
    )
    env = envelope(image)
    floor = np.median(env, axis=1, keepdims=True) + 1e-12
    wavelength = v * line.period_ns
    size = (max(3, int(wavelength / 2 / 0.0025)) | 1, max(3, int(wavelength / 2 / (line.x_m[1] - line.x_m[0]))) | 1)
    peaks = (env == ndimage.maximum_filter(env, size=size, mode="nearest")) & (env > snr * floor)
    peaks &= env > 0.01 * float(env.max())
    peaks[: int(0.01 / 0.0025)] = False  # the first centimetre is the surface, not a target
    iz, ix = np.nonzero(peaks)
    order = np.argsort(-env[iz, ix])
    apex_t = diffraction_times(np.zeros(1), z, v, gpr.antenna_height_m, gpr.tx_rx_offset_m)[0]
    return [(float(line.x_m[ix[k]]), float(apex_t[iz[k]]), float(env[iz[k], ix[k]])) for k in order]


def _pick_column(line: LineData, col: int, t_pred: float, polarity: float) -> tuple[float, float] | None:
    """Main-lobe peak (time, strength = polarity × amplitude > 0) within the window around t_pred."""
    half = _PICK_WINDOW_PERIODS * line.period_ns / line.dt_ns
    centre = (t_pred + line.t0_ns) / line.dt_ns
    lo, hi = math.floor(centre - half), math.ceil(centre + half)
    trace = line.data[col]
    if lo < 1 or hi >= len(trace) - 1:
        return None
    seg = polarity * trace[lo : hi + 1]
    i = int(np.argmax(seg))
    if i == 0 or i == len(seg) - 1 or seg[i] <= 0.0:
        return None
    a, b, c = seg[i - 1], seg[i], seg[i + 1]
    denom = a - 2.0 * b + c
    frac = 0.5 * (a - c) / denom if denom < 0 else 0.0
    return float(line.time_of(lo + i + frac)), float(b - 0.25 * (a - c) * frac)


def _pick_along(
    line: LineData, predicted: FloatArray, apex_col: int, polarity: float, floor: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Walk outward from the apex column along the predicted curve; stop after a few misses."""
    cols, times, amps = [], [], []
    max_jump = _MAX_JUMP_PERIODS * line.period_ns
    for step in (1, -1):
        misses = 0
        col = apex_col if step == 1 else apex_col - 1
        last_misfit: float | None = None
        while 0 <= col < len(line.x_m) and misses < _MAX_MISSES and np.isfinite(predicted[col]):
            pick = _pick_column(line, col, float(predicted[col]), polarity)
            misfit = None if pick is None else pick[0] - float(predicted[col])
            # A pick that jumps away from the curve has left it for a crossing event.
            if (pick is not None and misfit is not None and pick[1] > floor
                    and (last_misfit is None or abs(misfit - last_misfit) < max_jump * (misses + 1))):
                cols.append(col)
                times.append(pick[0])
                amps.append(pick[1])
                misses, last_misfit = 0, misfit
            else:
                misses += 1
            col += step
        if misses >= _MAX_MISSES and len(cols) > 2 * _END_TRIM:
            # The walk lost the curve: its last picks were already drifting onto whatever ended it.
            del cols[-_END_TRIM:], times[-_END_TRIM:], amps[-_END_TRIM:]
    order = np.argsort(cols)
    strength = np.array(amps)[order]
    return line.x_m[np.array(cols, dtype=np.intp)[order]], np.array(times)[order], polarity * strength


def _point_fit(x: FloatArray, t: FloatArray, x0: float, z0: float, v0: float, gpr: GprConfig) -> FloatArray:
    """Least-squares point-diffractor fit (x0, depth, v) of picks — used only to steer the picking."""

    def residual(p: FloatArray) -> FloatArray:
        return cylinder_times(x, p[0], p[1], 0.0, p[2], gpr) - t

    lb = [x0 - 0.2, 0.005, V_BOUNDS_M_PER_NS[0]]
    ub = [x0 + 0.2, _POINT_DEPTH_MAX_M, V_BOUNDS_M_PER_NS[1]]
    start = np.clip([x0, z0, v0], lb, ub)
    sol = optimize.least_squares(residual, start, bounds=(lb, ub), loss="soft_l1", f_scale=0.02)
    return np.asarray(sol.x)


def track_hyperbola(
    line: LineData, x_c: float, t_c: float, v: float, gpr: GprConfig, *, aperture_deg: float = FIT_APERTURE_DEG
) -> HyperbolaPicks | None:
    """Pick the hyperbola whose apex is near (x_c, t_c): predict, pick, refit, pick again (3 rounds).

    The prediction is a point diffractor whose (apparent) velocity is refitted to every round's
    picks, starting from v: a wrong guess, a pipe's radius or an oblique crossing (a wider
    hyperbola) then bend the prediction towards the data instead of cutting the flanks short.
    """
    dx = float(line.x_m[1] - line.x_m[0])
    col = round((x_c - float(line.x_m[0])) / dx)
    lo, hi = max(0, col - 2), min(len(line.x_m), col + 3)
    s_lo = max(0, int((t_c + line.t0_ns - 0.5 * line.period_ns) / line.dt_ns))
    s_hi = min(line.data.shape[1], int((t_c + line.t0_ns + 0.5 * line.period_ns) / line.dt_ns) + 1)
    if s_hi - s_lo < 3:
        return None
    block = line.data[lo:hi, s_lo:s_hi]
    bi, bs = np.unravel_index(int(np.argmax(np.abs(block))), block.shape)
    apex_col, polarity = lo + int(bi), float(np.sign(block[bi, bs]))
    apex = _pick_column(line, apex_col, float(line.time_of(float(s_lo + bs))), polarity)
    if apex is None:
        return None
    floor = max(4.0 * line.noise, 0.05 * apex[1])
    x0, z, vv = float(line.x_m[apex_col]), depth_for_apex_time(apex[0], v, gpr), v
    x, t, a = np.zeros(0), np.zeros(0), np.zeros(0)
    for _ in range(3):
        half_width = z * math.tan(math.radians(aperture_deg)) + 2 * dx
        predicted = cylinder_times(line.x_m, x0, z, 0.0, vv, gpr)
        predicted[np.abs(line.x_m - x0) > half_width] = np.nan
        x, t, a = _pick_along(line, predicted, apex_col, polarity, floor)
        if len(x) < _MIN_PICKS:
            return None
        x0, z, vv = (float(p) for p in _point_fit(x, t, x0, z, vv, gpr))
    if not _is_hyperbola(x, t, (x0, z, vv), line.period_ns):
        return None
    apex_x, apex_t = float(x[np.argmin(t)]), float(t.min())
    return HyperbolaPicks(x, t, a, polarity, apex_x, apex_t, polarity * float(apex[1]), (x0, z, vv))


def _is_hyperbola(x: FloatArray, t: FloatArray, model: tuple[float, float, float], period_ns: float) -> bool:
    """Whether picks form a diffraction hyperbola, not a layer or a dipping band.

    The apex must lie inside the picks with both flanks rising from it (a dipping layer rises on
    one side only), and the point fit must give a physical velocity and depth (a flat layer fits
    only with v or depth at their bounds).
    """
    apex = int(np.argmin(t))
    left, right = apex, len(t) - 1 - apex
    if min(left, right) < _MIN_FLANK_PICKS:
        return False
    rise = min(float(t[0] - t[apex]), float(t[-1] - t[apex]))
    _, depth, v_app = model
    v_inside = V_BOUNDS_M_PER_NS[0] * 1.01 < v_app < V_BOUNDS_M_PER_NS[1] * 0.99
    return rise > _MIN_FLANK_RISE_PERIODS * period_ns and v_inside and depth < _POINT_DEPTH_MAX_M * 0.99


def _on_curve(h: HyperbolaPicks, x: float, t: float, tolerance_ns: float) -> bool:
    """Whether (x, t) lies on the picked curve h (within its picked span)."""
    if x < h.x_m[0] - 0.02 or x > h.x_m[-1] + 0.02:
        return False
    return bool(abs(float(np.interp(x, h.x_m, h.t_ns)) - t) < tolerance_ns)


def hyperbolas_of_line(
    line: LineData, v: float, gpr: GprConfig, cfg: InterpretationConfig, *, max_targets: int = 60,
) -> list[HyperbolaPicks]:
    """Track the hyperbolas of a line, strongest first, without duplicates, inner echoes or multiples.

    An event right below a stronger one (same x) within the delay of a pipe's inner-bottom echo, or
    at about twice its time (surface multiple), belongs to it and is dropped. The slab bottom and
    flat bands are gone with the background; what is left of them under the pipes' shadows is flat,
    and the cylinder fit rejects it (see `interpret`).
    """
    kept: list[HyperbolaPicks] = []
    inner_delay_max = 4.0 * MAX_RADIUS_M / C_M_PER_NS
    for x_c, t_c, _ in find_apex_candidates(line, v, gpr, cfg)[:max_targets]:
        if any(_on_curve(h, x_c, t_c, 0.6 * line.period_ns) for h in kept):
            continue
        hyp = track_hyperbola(line, x_c, t_c, v, gpr)
        if hyp is None:
            continue
        belongs = any(
            abs(h.apex_x_m - hyp.apex_x_m) < 0.05 and hyp.apex_t_ns > h.apex_t_ns
            and (hyp.apex_t_ns - h.apex_t_ns < inner_delay_max
                 or abs(hyp.apex_t_ns - 2.0 * h.apex_t_ns) < line.period_ns)
            for h in kept
        )
        if belongs or any(_on_curve(h, hyp.apex_x_m, hyp.apex_t_ns, 0.3 * line.period_ns) for h in kept):
            continue
        kept.append(hyp)
    return kept


def without_interference(hyperbolas: Sequence[HyperbolaPicks], gpr: GprConfig) -> list[HyperbolaPicks]:
    """Each hyperbola without the picks where another one's curve, or its surface multiple, crosses it.

    Where two flanks cross, the picked peak is the sum of both and belongs to neither; only
    crossings with echoes at least a third as strong as this pick count.
    """
    period = 1000.0 / gpr.centre_frequency_mhz
    air = 2.0 * gpr.antenna_height_m / C_M_PER_NS
    out = []
    for i, h in enumerate(hyperbolas):
        keep = np.ones(len(h.x_m), dtype=bool)
        strength = np.abs(h.amplitude)
        for j, other in enumerate(hyperbolas):
            if j == i:
                continue
            x0, z, v_app = other.point_model
            t_other = cylinder_times(h.x_m, x0, z, 0.0, v_app, gpr)
            loud = abs(other.apex_amplitude) > strength / 3.0
            keep &= ~(loud & (np.abs(h.t_ns - t_other) < 0.6 * period))
            keep &= ~((0.25 * abs(other.apex_amplitude) > strength / 3.0)
                      & (np.abs(h.t_ns - (2.0 * t_other - air)) < 0.6 * period))
        if keep.sum() >= _MIN_PICKS and not keep.all():
            h = replace(h, x_m=h.x_m[keep], t_ns=h.t_ns[keep], amplitude=h.amplitude[keep])
        out.append(h)
    return out


def fit_shared_velocity(
    hyperbolas: Sequence[HyperbolaPicks], gpr: GprConfig, v0: float, sin_cross: Sequence[float] | None = None
) -> tuple[float, float, FloatArray, FloatArray]:
    """One velocity for all hyperbolas, each with its own (x0, dc, R) at a fixed crossing sine.

    The crossing sines stay fixed (from the neighbouring lines): freed, they trade off against the
    velocity (a wider hyperbola reads as oblique or as faster) and the estimate degrades (measured:
    −2.4 % → −5.7 % on the oblique scene). Robust least squares; returns (v, std of v, per-target
    parameters (n, 3), per-target RMS residual in ns).
    """
    n = len(hyperbolas)
    sizes = [len(h.t_ns) for h in hyperbolas]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    x_all = np.concatenate([h.x_m for h in hyperbolas])
    t_all = np.concatenate([h.t_ns for h in hyperbolas])
    owner = np.repeat(np.arange(n), sizes)
    sin_all = np.asarray([1.0] * n if sin_cross is None else list(sin_cross), dtype=np.float64)[owner]

    def residual(p: FloatArray) -> FloatArray:
        per_pick = p[1:].reshape(n, 3)[owner]
        times = cylinder_times(x_all, per_pick[:, 0], per_pick[:, 1], per_pick[:, 2], p[0], gpr, sin_all)
        return np.asarray(times - t_all, dtype=np.float64)

    sparsity = lil_matrix((starts[-1], 1 + 3 * n), dtype=np.int8)
    sparsity[:, 0] = 1
    p0, lb, ub = [v0], [V_BOUNDS_M_PER_NS[0]], [V_BOUNDS_M_PER_NS[1]]
    for i, h in enumerate(hyperbolas):
        sparsity[starts[i] : starts[i + 1], 1 + 3 * i : 4 + 3 * i] = 1
        z = depth_for_apex_time(h.apex_t_ns, v0, gpr)
        p0 += [h.apex_x_m, z + 0.02, 0.02]
        lb += [h.apex_x_m - 0.2, 0.005, 0.0]
        ub += [h.apex_x_m + 0.2, 3.0, MAX_RADIUS_M]
    sol = optimize.least_squares(
        residual, np.clip(p0, lb, ub), bounds=(lb, ub), jac_sparsity=sparsity, loss="soft_l1", f_scale=0.01,
        x_scale="jac", max_nfev=200,
    )
    r = sol.fun
    rms = np.array([math.sqrt(float(np.mean(r[starts[i] : starts[i + 1]] ** 2))) for i in range(n)])
    jac = sol.jac.toarray() if hasattr(sol.jac, "toarray") else np.asarray(sol.jac)
    dof = max(1, len(r) - len(sol.x))
    cov = np.linalg.pinv(jac.T @ jac) * float(r @ r) / dof
    return float(sol.x[0]), math.sqrt(max(float(cov[0, 0]), 0.0)), sol.x[1:].reshape(n, 3), rms


def _line_direction(bscan: BScan) -> FloatArray:
    """Horizontal unit vector from the first to the last trace."""
    d = np.asarray(bscan.positions[-1, :2] - bscan.positions[0, :2], dtype=np.float64)
    return d / max(float(np.hypot(d[0], d[1])), 1e-9)


def link_crossings(
    apices: Sequence[Sequence[tuple[FloatArray, float, float]]], directions: Sequence[FloatArray]
) -> list[list[float | None]]:
    """Sine of the crossing angle of every apex (xy, t, polarity), from its twins on the neighbouring lines.

    A twin has the same polarity, nearly the same apex time (a pipe barely changes depth between
    lines) and lies within 0.4 m; the pipe runs from the previous line's twin to the next one's.
    Lines are taken in the order given (the survey's order of parallel lines). None: no twin.
    """
    out: list[list[float | None]] = []
    for i, line in enumerate(apices):
        sines: list[float | None] = []
        for xy, t, polarity in line:
            twins = []
            for j in (i - 1, i + 1):
                if not 0 <= j < len(apices):
                    continue
                near = [(float(np.linalg.norm(b - xy)), b) for b, tb, pb in apices[j]
                        if pb == polarity and abs(tb - t) < 0.5 and float(np.linalg.norm(b - xy)) < 0.4]
                if near:
                    twins.append((j, min(near, key=lambda n: n[0])[1]))
            if not twins:
                sines.append(None)
                continue
            ends = [b for _, b in twins]
            run = ends[-1] - ends[0] if len(ends) == 2 else (ends[0] - xy) * (twins[0][0] - i)
            unit = run / max(float(np.linalg.norm(run)), 1e-9)
            sines.append(abs(float(unit[0] * directions[i][1] - unit[1] * directions[i][0])))
        out.append(sines)
    return out


def _sin_std(sin_cross: float) -> float:
    """Uncertainty of a crossing sine from apices ~0.1 m apart known to a few mm (angle σ ≈ 0.025 rad)."""
    return math.sqrt(max(0.0, 1.0 - sin_cross**2)) * _ANGLE_STD_RAD + 0.5 * _ANGLE_STD_RAD**2


def estimate_velocity(
    bscans: Sequence[BScan], gpr: GprConfig, cfg: InterpretationConfig
) -> VelocityEstimate:
    """Survey-wide velocity from all hyperbolas of all lines (one shared v; see the module docstring).

    Oblique pipes give wider hyperbolas, which read as a higher velocity: the crossing angle of each
    hyperbola comes from its twins on the neighbouring lines (`link_crossings`) and enters the fit;
    where no twin exists the pipe is taken as crossing at right angles. Hyperbolas whose fit stays
    poor (RMS over 3× the median and over a twentieth of a period: a surface multiple, crossing
    flanks) are dropped and the fit repeated.
    """
    per_line: list[list[HyperbolaPicks]] = []
    apices: list[list[tuple[FloatArray, float, float]]] = []
    for bscan in bscans:
        line = prepare_line(bscan, gpr)
        found = without_interference(hyperbolas_of_line(line, V_GUESS_M_PER_NS, gpr, cfg), gpr)
        per_line.append(found)
        apices.append([(bscan.position_at(h.point_model[0])[:2], h.apex_t_ns, h.polarity) for h in found])
    linked = link_crossings(apices, [_line_direction(b) for b in bscans])
    hyperbolas = [h for found in per_line for h in found]
    sines = [1.0 if s is None else s for line_sines in linked for s in line_sines]
    crossings = tuple(
        CrossingHint((float(a[0][0]), float(a[0][1])), float(s), _sin_std(float(s)))
        for line_apices, line_sines in zip(apices, linked, strict=True)
        for a, s in zip(line_apices, line_sines, strict=True) if s is not None
    )
    if not hyperbolas:
        raise InterpretationError(
            "no reflection hyperbola found to estimate the velocity from; give the slab's eps_r in the config"
        )
    v0 = V_GUESS_M_PER_NS
    period = 1000.0 / gpr.centre_frequency_mhz
    for _ in range(3):
        v, std, _, rms = fit_shared_velocity(hyperbolas, gpr, v0, sines)
        good = (rms <= 3.0 * float(np.median(rms))) | (rms <= period / 20.0)
        if good.all():
            break
        hyperbolas = [h for h, g in zip(hyperbolas, good, strict=True) if g]
        sines = [s for s, g in zip(sines, good, strict=True) if g]
        v0 = v
    return VelocityEstimate(v, std, len(hyperbolas), crossings)
