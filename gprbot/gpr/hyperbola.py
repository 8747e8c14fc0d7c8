"""Hyperbola picking: apex candidates from the migrated image, main-lobe picks along each hyperbola.

Every pick is the main-lobe peak of a reflection (the same wavelet phase that defines time zero);
the picking is steered by point-diffractor models (`line_model.cylinder_times` with R = 0).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage, optimize

from gprbot.config import GprConfig, InterpretationConfig
from gprbot.gpr.line_model import LineData, cylinder_times, depth_for_apex_time
from gprbot.gpr.migration import depth_axis, diffraction_times, envelope, kirchhoff_migrate
from gprbot.gpr.traveltime import C_M_PER_NS

FloatArray = NDArray[np.float64]

V_BOUNDS_M_PER_NS = (0.05, 0.25)
FIT_APERTURE_DEG = 60.0
MAX_RADIUS_M = 0.15
_PICK_WINDOW_PERIODS = 0.35  # < 0.39 T: the Ricker's side lobes never enter the window
_MAX_MISSES = 3
_MIN_FLANK_PICKS = 3
_MIN_FLANK_RISE_PERIODS = 0.25
_MIN_MIRRORED_RISE_PERIODS = 0.05  # a flank cut short by a crossing event: how far it must rise, ...
_MIN_MIRRORED_PICKS = 3  # ... how many of its picks nearest the apex must mirror the other flank, ...
_MIRROR_TOLERANCE_PERIODS = 0.1  # ... and how closely
_POINT_DEPTH_MAX_M = 3.0
_END_TRIM = 2
_MAX_JUMP_PERIODS = 0.06  # largest change of misfit between neighbouring picks
_MIN_PICKS = 7


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
    only with v or depth at their bounds). A flank cut short where a stronger hyperbola crosses it
    (a tee's branch beside its main) counts when it mirrors the other flank about the apex.
    """
    apex = int(np.argmin(t))
    left, right = apex, len(t) - 1 - apex
    if min(left, right) < _MIN_FLANK_PICKS:
        return False
    _, depth, v_app = model
    v_inside = V_BOUNDS_M_PER_NS[0] * 1.01 < v_app < V_BOUNDS_M_PER_NS[1] * 0.99
    if not v_inside or depth >= _POINT_DEPTH_MAX_M * 0.99:
        return False
    rises = (float(t[0] - t[apex]), float(t[-1] - t[apex]))
    threshold = _MIN_FLANK_RISE_PERIODS * period_ns
    if min(rises) > threshold:
        return True
    if max(rises) <= threshold or min(rises) <= _MIN_MIRRORED_RISE_PERIODS * period_ns:
        return False
    short = slice(0, apex) if left < right else slice(apex + 1, len(t))
    long = slice(apex + 1, len(t)) if left < right else slice(0, apex)
    distance = np.abs(x - x[apex])
    order = np.argsort(distance[long])
    mirrored = np.interp(distance[short], distance[long][order], t[long][order], right=np.nan)
    # Nearest the apex first: past the crossing the picks follow the other event, not this one.
    nearest = np.argsort(distance[short])[:_MIN_MIRRORED_PICKS]
    return bool(np.all(np.abs(mirrored - t[short])[nearest] < _MIRROR_TOLERANCE_PERIODS * period_ns))


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

