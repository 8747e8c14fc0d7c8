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
    model = _Model(prep.antenna_height_m, prep.tx_rx_offset_m, sigma_t, free_velocity)
    p, r, J, c = _levenberg_marquardt(model, _Members(x, t, mask, v0, lo, hi), p)
    best = c.reshape(n_starts, n_sel).argmin(axis=0) * n_sel + np.arange(n_sel)
    sigmas = _sigmas(J[best], r[best], mask[best], n_par)
    for k, i in enumerate(usable):
        b, sig = int(best[k]), sigmas[k]
        rb = r[b][mask[b]]
        vel = float(p[b, 3]) if free_velocity else float(v0[b])
        out[i] = CylinderFit(float(p[b, 0]), float(p[b, 1]), float(p[b, 2]), vel, float(sig[0]), float(sig[1]),
                             float(sig[2]), float(sig[3]) if free_velocity else 0.0,
                             math.sqrt(float(np.mean(rb * rb))) * sigma_t, int(mask[b].sum()))
    return out


@dataclass(frozen=True)
class _Model:
    """What the residuals of every member share: the antenna, the picks' error, whether v is free."""

    height: float
    offset: float
    sigma_t: float
    free_velocity: bool

    def residuals(self, q: FloatArray, m: _Members) -> tuple[FloatArray, FloatArray]:
        """Weighted residuals (members, picks) of parameters q and their Jacobian (members, picks, params)."""
        vel = q[:, 3:4] if self.free_velocity else m.v0[:, None]
        zc = q[:, 1:2] + q[:, 2:3]
        model, g_x0, g_zc, g_r, g_v = cylinder_time_gradient(m.x, q[:, 0:1], zc, q[:, 2:3], vel, self.height,
                                                             self.offset)
        cols = [g_x0, g_zc, g_r + g_zc] + ([g_v] if self.free_velocity else [])
        jac = np.where(m.mask[..., None], np.stack(cols, axis=-1) / self.sigma_t, 0.0)
        return np.where(m.mask, (model - m.t) / self.sigma_t, 0.0), jac


@dataclass(frozen=True)
class _Members:
    """The picks (padded), fixed velocity and bounds of the members of a batch, one row each."""

    x: FloatArray
    t: FloatArray
    mask: NDArray[np.bool_]
    v0: FloatArray
    lo: FloatArray
    hi: FloatArray

    def only(self, keep: NDArray[np.bool_]) -> _Members:
        """The members where `keep` is true."""
        return _Members(self.x[keep], self.t[keep], self.mask[keep], self.v0[keep], self.lo[keep], self.hi[keep])


def _soft_l1(r: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Each member's robust cost, and sqrt(1 + (r / scale)²) per residual (its IRLS weight is the inverse)."""
    root = np.sqrt(1.0 + (r / ROBUST_SCALE) ** 2)
    return np.asarray(np.sum(2.0 * ROBUST_SCALE**2 * (root - 1.0), axis=1)), root


def _levenberg_marquardt(
    model: _Model, members: _Members, p: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Bounded, damped Gauss-Newton on every member at once from p: (parameters, residuals, Jacobian, cost).

    Only members still improving are iterated: a converged one is frozen (most of a batch converges in a
    few steps, and the slowest used to set the work for all). The members still iterating are kept in
    arrays of their own, written back when they finish: indexing the whole batch each step cost as much
    as a step's arithmetic on a typical batch.
    """
    eye = np.eye(p.shape[1])
    p = p.copy()  # p, r, J, c: every member's result; pa, ra, Ja, ca...: those of the active ones
    r, J = model.residuals(p, members)
    c, root = _soft_l1(r)
    index = np.arange(len(p))  # of the active members
    pa, ra, Ja, ca, root_a, la = p, r, J, c, root, np.full(len(p), 1e-2)
    for _ in range(ITERATIONS):
        w = 1.0 / root_a  # soft-L1 as iteratively reweighted least squares
        JtW = np.swapaxes(Ja * w[..., None], 1, 2)
        A = JtW @ Ja
        g = np.einsum("bpn,bn->bp", JtW, ra)
        # The damping λ·diag on the diagonal (products by the identity's 1s and 0s, as an einsum would make).
        diag = A.diagonal(axis1=1, axis2=2) + 1e-12
        damped = A + (la[:, None] * diag)[:, :, None] * eye
        step = -np.linalg.solve(damped, g[..., None])[..., 0]
        trial = np.minimum(np.maximum(pa + step, members.lo), members.hi)  # np.clip costs more on small arrays
        r_trial, J_trial = model.residuals(trial, members)
        c_trial, root_trial = _soft_l1(r_trial)
        better = c_trial < ca
        gain = np.where(better, (ca - c_trial) / np.maximum(ca, 1e-12), 0.0)
        row_better = better[:, None]
        pa, ra = np.where(row_better, trial, pa), np.where(row_better, r_trial, ra)
        root_a, Ja = np.where(row_better, root_trial, root_a), np.where(better[:, None, None], J_trial, Ja)
        ca = np.where(better, c_trial, ca)
        la = np.where(better, la * 0.3, la * 10.0)
        # Done: improving by less than a part in 10⁴, or given up.
        done = (better & (gain < 1e-4)) | (la > 1e6)
        if done.any():
            finished = index[done]
            p[finished], r[finished], J[finished], c[finished] = pa[done], ra[done], Ja[done], ca[done]
            keep = ~done
            index = index[keep]
            pa, ra, Ja, ca, root_a, la = pa[keep], ra[keep], Ja[keep], ca[keep], root_a[keep], la[keep]
            members = members.only(keep)
            if not len(index):
                break
    p[index], r[index], J[index], c[index] = pa, ra, Ja, ca
    return p, r, J, c


def _sigmas(J: FloatArray, r: FloatArray, mask: NDArray[np.bool_], n_par: int) -> FloatArray:
    """1-sigma errors (members, params) of each member's parameters from its Jacobian and residuals at the fit.

    The normal matrices are made one member at a time (their sums must not see the padding) and
    pseudo-inverted in one batched call (the same LAPACK routine per matrix, so the same floats).
    """
    normals, scales = [], []
    for jm, rm, m in zip(J, r, mask, strict=True):
        jb, rb = jm[m], rm[m]
        dof = max(1, int(m.sum()) - n_par)
        scales.append(max(1.0, float(rb @ rb) / dof) * correlation_inflation(rb))
        normals.append(jb.T @ jb)
    cov = np.linalg.pinv(np.stack(normals)) * np.array(scales)[:, None, None]
    finite = np.all(np.isfinite(cov), axis=(1, 2))
    diag = np.sqrt(np.maximum(np.einsum("bpp->bp", cov), 0.0))
    return np.where(finite[:, None], diag, np.inf)
