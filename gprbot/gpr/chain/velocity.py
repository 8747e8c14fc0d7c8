"""Stage 3: the wave velocity from many diffractions at once, with its uncertainty and how it was found.

Each hyperbola's picks were fitted with the velocity free (`fit.fit_cylinder`); its estimate comes with
a variance that is wide when its radius and velocity trade off (a large pipe seen over a small
aperture) and narrow for a thin bar. The survey velocity is their inverse-variance mean after the
estimates more than three (combined) sigmas from the weighted median are dropped; its uncertainty is the
larger of the formal error and the scatter of the estimates that were kept.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gprbot.gpr.chain.fit import V_BOUNDS, CylinderFit

MAX_RELATIVE_SIGMA = 0.25  # a hyperbola that says less than ±25 % about v is not asked
MIN_SIGMA_RELATIVE = 0.005  # no velocity is known better than ±0.5 % from picks on one line


@dataclass(frozen=True)
class VelocityEstimate:
    """The velocity (m/ns), its 1-sigma uncertainty, the number of diffractions used, and how."""

    v: float
    sigma: float
    n_used: int
    method: str


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The value below which half the total weight lies."""
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def combine_velocities(fits: Sequence[CylinderFit]) -> VelocityEstimate | None:
    """The survey velocity from free-velocity cylinder fits; None when no fit constrains it."""
    usable = [f for f in fits if f.sigma_v > 0 and f.sigma_v < MAX_RELATIVE_SIGMA * f.v
              and V_BOUNDS[0] * 1.02 < f.v < V_BOUNDS[1] * 0.98]
    if not usable:
        return None
    v = np.array([f.v for f in usable])
    s = np.maximum(np.array([f.sigma_v for f in usable]), MIN_SIGMA_RELATIVE * v)
    w = 1.0 / s**2
    med = _weighted_median(v, w)
    spread = 1.4826 * _weighted_median(np.abs(v - med), w) if len(v) > 2 else 0.0
    keep = np.abs(v - med) <= 3.0 * np.sqrt(s**2 + spread**2)
    v, s, w = v[keep], s[keep], w[keep]
    mean = float(np.sum(w * v) / np.sum(w))
    formal = float(1.0 / np.sqrt(np.sum(w)))
    scatter = float(np.sqrt(np.sum(w * (v - mean) ** 2) / np.sum(w) / max(len(v) - 1, 1))) if len(v) > 1 else 0.0
    n = len(v)
    how = (f"cylinder fits of {n} diffraction hyperbolas (inverse-variance mean)" if n > 1
           else "the cylinder fit of one diffraction hyperbola (weak: radius and velocity trade off)")
    return VelocityEstimate(mean, max(formal, scatter), n, how)
