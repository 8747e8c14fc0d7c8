"""Stage 4b: cylinders fitted to hyperbolas' picks — centre, top depth, radius, and velocity when free.

The model is the refracted two-way time to the cylinder's specular point (antenna height and Tx–Rx
offset, `geometry.cylinder_time`). Parameters are the along-track centre x0, the depth of the top d
(the centre lies at d + R), the radius R and — when not given — the velocity. All of a line's
hyperbolas are fitted at once by a batched, bounded Levenberg–Marquardt with a robust (soft-L1) loss:
one numpy evaluation serves every hyperbola, which keeps a line to a few milliseconds. The covariance
says what the picks support: on one hyperbola R and v trade off, so a free-velocity fit of a large pipe
has a wide v interval and the survey velocity weighs it accordingly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.gpr.chain.geometry import cylinder_time_gradient
from gprbot.gpr.chain.picks import Picks
from gprbot.gpr.chain.prepare import PreparedBScan

FloatArray = NDArray[np.float64]

R_MAX_M = 0.2
V_BOUNDS = (0.035, 0.29)
MIN_PICKS = 5
PICK_STD_PERIODS = 0.03  # floor of a pick's timing error, in periods
ROBUST_SCALE = 2.0  # soft-L1 scale, in pick standard deviations
ITERATIONS = 20
START_RADII_M = np.array([0.01])
MAX_CORRELATION = 0.95


@dataclass(frozen=True)
class CylinderFit:
    """A fitted reflector: centre x0 and depth (m), radius, velocity (m/ns), 1-sigma errors, misfit."""

    x0_m: float
    top_m: float
    radius_m: float
    v: float
    sigma_x0_m: float
    sigma_top_m: float
    sigma_radius_m: float
    sigma_v: float
    rms_ns: float
    n_picks: int

    @property
    def depth_m(self) -> float:
        """Depth of the centre below the surface (m)."""
        return self.top_m + self.radius_m


def _padded(picks: Sequence[Picks]) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """(x, t, mask) of the picks as (batch, longest) arrays."""
    n = max(len(p.x_m) for p in picks)
    x, t = np.zeros((len(picks), n)), np.zeros((len(picks), n))
    mask = np.zeros((len(picks), n), dtype=bool)
    for i, p in enumerate(picks):
        k = len(p.x_m)
        x[i, :k], t[i, :k], mask[i, :k] = p.x_m, p.t_ns, True
        x[i, k:] = p.x_m[-1] if k else 0.0
    return x, t, mask


def correlation_inflation(residuals: FloatArray) -> float:
    """Variance factor for residuals that run smooth along the picks: (1 + ρ) / (1 − ρ), ρ their lag-1 correlation.

    Where the model and the data differ (the wavelet changes along a flank, a neighbour's tail), the
    misfit is a smooth curve, not white noise; n such picks carry the weight of n (1 − ρ)/(1 + ρ)
    independent ones, and the covariance of white errors would claim a radius the curve does not show.
    """
    r = residuals - residuals.mean()
    denom = float(r @ r)
    if len(r) < 4 or denom <= 0.0:
        return 1.0
    rho = min(MAX_CORRELATION, max(0.0, float(r[1:] @ r[:-1]) / denom))
    return (1.0 + rho) / (1.0 - rho)


def fit_cylinders(
    prep: PreparedBScan, picks: Sequence[Picks], v: float | Sequence[float], *, free_velocity: bool
) -> list[CylinderFit | None]:
    """Fit every hyperbola's picks (None where there are too few); `v` is the start or the fixed velocity."""
    usable = [i for i, p in enumerate(picks) if len(p.x_m) >= MIN_PICKS]
    out: list[CylinderFit | None] = [None] * len(picks)
    if not usable:
        return out
    sel = [picks[i] for i in usable]
    x, t, mask = _padded(sel)
    v0 = np.broadcast_to(np.asarray(v, dtype=np.float64), (len(picks),))[usable]
    sigma_t = max(PICK_STD_PERIODS * prep.period_ns, 0.5 * prep.dt_ns)
    h, off = prep.antenna_height_m, prep.tx_rx_offset_m
    n_par = 4 if free_velocity else 3
    # Several starting radii per hyperbola, all in one batch: a thin bar and a large pipe are separate
    # minima of the misfit, and a start near the wrong one stays there.
    n_sel, n_starts = len(sel), len(START_RADII_M)
    x, t, mask = np.tile(x, (n_starts, 1)), np.tile(t, (n_starts, 1)), np.tile(mask, (n_starts, 1))
    v0 = np.tile(v0, n_starts)
    apex = np.where(mask, t, np.inf).argmin(axis=1)
    rows = np.arange(len(x))
    p = np.zeros((len(x), n_par))
    p[:, 0] = x[rows, apex]
    p[:, 1] = np.maximum(0.003, 0.5 * v0 * t[rows, apex])
    p[:, 2] = np.repeat(START_RADII_M, n_sel)
    if free_velocity:
        p[:, 3] = v0
    lo = np.stack([x.min(axis=1) - 0.05, np.zeros(len(x)), np.zeros(len(x))]
                  + ([np.full(len(x), V_BOUNDS[0])] if free_velocity else []), axis=1)
    hi = np.stack([x.max(axis=1) + 0.05, np.full(len(x), 5.0), np.full(len(x), R_MAX_M)]
                  + ([np.full(len(x), V_BOUNDS[1])] if free_velocity else []), axis=1)

    def residual_and_jacobian(q: FloatArray, rows: NDArray[np.intp]) -> tuple[FloatArray, FloatArray]:
        xs, ts, ms = x[rows], t[rows], mask[rows]
        vel = q[:, 3:4] if free_velocity else v0[rows, None]
        zc = q[:, 1:2] + q[:, 2:3]
        model, g_x0, g_zc, g_r, g_v = cylinder_time_gradient(xs, q[:, 0:1], zc, q[:, 2:3], vel, h, off)
        cols = [g_x0, g_zc, g_r + g_zc] + ([g_v] if free_velocity else [])
        jac = np.where(ms[..., None], np.stack(cols, axis=-1) / sigma_t, 0.0)
        return np.where(ms, (model - ts) / sigma_t, 0.0), jac

    def cost(r: FloatArray) -> FloatArray:
        return np.asarray(np.sum(2.0 * ROBUST_SCALE**2 * (np.sqrt(1.0 + (r / ROBUST_SCALE) ** 2) - 1.0), axis=1))

    lam = np.full(len(x), 1e-2)
    r, J = residual_and_jacobian(p, rows)
    c = cost(r)
    active = rows
    for _ in range(ITERATIONS):
        # Only members still improving are iterated: a converged one is frozen (most of a batch converges
        # in a few steps, and the slowest used to set the work for all).
        ra, Ja, pa, la = r[active], J[active], p[active], lam[active]
        w = 1.0 / np.sqrt(1.0 + (ra / ROBUST_SCALE) ** 2)  # soft-L1 as iteratively reweighted least squares
        JtW = np.swapaxes(Ja * w[..., None], 1, 2)
        A = JtW @ Ja
        g = np.einsum("bpn,bn->bp", JtW, ra)
        diag = np.einsum("bpp->bp", A) + 1e-12
        damped = A + la[:, None, None] * np.einsum("bp,pq->bpq", diag, np.eye(n_par))
        step = -np.linalg.solve(damped, g[..., None])[..., 0]
        trial = np.minimum(np.maximum(pa + step, lo[active]), hi[active])  # np.clip costs more on small arrays
        r_trial, J_trial = residual_and_jacobian(trial, active)
        c_trial = cost(r_trial)
        better = c_trial < c[active]
        gain = np.where(better, (c[active] - c_trial) / np.maximum(c[active], 1e-12), 0.0)
        p[active] = np.where(better[:, None], trial, pa)
        r[active] = np.where(better[:, None], r_trial, ra)
        J[active] = np.where(better[:, None, None], J_trial, Ja)
        c[active] = np.where(better, c_trial, c[active])
        lam[active] = np.where(better, la * 0.3, la * 10.0)
        # Done: improving by less than a part in 10⁴, or given up.
        active = active[~((better & (gain < 1e-4)) | (lam[active] > 1e6))]
        if not len(active):
            break
    best = c.reshape(n_starts, n_sel).argmin(axis=0) * n_sel + np.arange(n_sel)
    for k, i in enumerate(usable):
        b = int(best[k])
        m = mask[b]
        jb, rb = J[b][m], r[b][m]
        dof = max(1, int(m.sum()) - n_par)
        scale = max(1.0, float(rb @ rb) / dof) * correlation_inflation(rb)
        cov = np.linalg.pinv(jb.T @ jb) * scale
        sig = np.sqrt(np.maximum(np.diag(cov), 0.0)) if np.all(np.isfinite(cov)) else np.full(n_par, np.inf)
        vel = float(p[b, 3]) if free_velocity else float(v0[b])
        out[i] = CylinderFit(float(p[b, 0]), float(p[b, 1]), float(p[b, 2]), vel, float(sig[0]), float(sig[1]),
                             float(sig[2]), float(sig[3]) if free_velocity else 0.0,
                             math.sqrt(float(np.mean(rb * rb))) * sigma_t, int(m.sum()))
    return out

