"""Classical migration of a B-scan into a depth image: Kirchhoff (refracted times) and Stolt f-k.

Both work on a uniform along-track grid (`resample_uniform` first) and return an image (nz, nx) on
the depth axis `z_m` (positive down). Kirchhoff sums each trace along the diffraction curve of every
image point using the exact refracted two-way time (antenna height, Tx–Rx offset in line), within a
limited aperture; Stolt is the constant-velocity f-k method, with height and offset corrected only
statically (time shift for the air gap, apex mapping for the offset) — faster, less exact.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from gprbot.errors import InterpretationError
from gprbot.gpr.bscan import BScan, binned_sums
from gprbot.gpr.traveltime import C_M_PER_NS, two_way_time

Float32Array = NDArray[np.float32]
FloatArray = NDArray[np.float64]
_IN_LINE = np.array([1.0, 0.0])


def resample_uniform(
    bscan: BScan, spacing_m: float, *, along_m: FloatArray | None = None
) -> tuple[Float32Array, FloatArray]:
    """Traces averaged into uniform along-track bins of `spacing_m`, empty bins interpolated.

    Returns (data (nx, n_samples), x_m (nx,)): x_m are the bin centres in along-track metres.
    `along_m` is `bscan.along_track_m()` where the caller has it already (it smooths the track: not free).
    """
    along = bscan.along_track_m() if along_m is None else along_m
    length = float(along.max() - along.min())
    n_bins = math.floor(length / spacing_m) + 1
    if n_bins < 2:
        raise InterpretationError(
            f"the line is {length:.3f} m long: too short for a {spacing_m} m grid; survey a longer line"
        )
    index = np.clip(np.round((along - along.min()) / spacing_m).astype(np.intp), 0, n_bins - 1)
    data = np.asarray(bscan.data, dtype=np.float64)
    sums = binned_sums(data, index, n_bins)
    counts = np.bincount(index, minlength=n_bins)
    filled = counts > 0
    out = np.empty_like(sums)
    out[filled] = sums[filled] / counts[filled, None]
    if not filled.all():
        centres = np.arange(n_bins, dtype=np.float64)
        fi = np.flatnonzero(filled)
        lo = np.clip(np.searchsorted(fi, centres, side="right") - 1, 0, len(fi) - 1)
        hi = np.clip(lo + 1, 0, len(fi) - 1)
        span = np.maximum(fi[hi] - fi[lo], 1)
        w = np.clip((centres - fi[lo]) / span, 0.0, 1.0)[:, None]
        interpolated = out[fi[lo]] * (1.0 - w) + out[fi[hi]] * w
        out[~filled] = interpolated[~filled]
    x_m = float(along.min()) + np.arange(n_bins, dtype=np.float64) * spacing_m
    return np.asarray(out, dtype=np.float32), np.asarray(x_m, dtype=np.float64)


def depth_axis(depth_max_m: float, dz_m: float = 0.0025) -> FloatArray:
    """Depth samples 0, dz, ..., depth_max (m, positive down)."""
    return np.arange(0.0, depth_max_m + 0.5 * dz_m, dz_m)


def diffraction_times(
    lags_m: FloatArray, z_m: FloatArray, v: float, antenna_height_m: float, tx_rx_offset_m: float
) -> FloatArray:
    """Two-way time (nk, nz) from an antenna `lag` m along the line to a point at depth z below 0."""
    mid = np.stack([lags_m, np.zeros_like(lags_m)], axis=-1)[:, None, :]
    point = np.zeros((1, len(z_m), 3))
    point[0, :, 2] = -np.maximum(z_m, 1e-4)
    return two_way_time(mid, point, v, antenna_height_m, tx_rx_offset_m, _IN_LINE)


def kirchhoff_migrate(
    data: NDArray[np.floating],
    x_m: FloatArray,
    dt_ns: float,
    t0_ns: float,
    z_m: FloatArray,
    v: float,
    *,
    antenna_height_m: float,
    tx_rx_offset_m: float,
    aperture_deg: float = 35.0,
) -> Float32Array:
    """Diffraction-summation migration with refracted two-way times; image (nz, nx).

    Each image point sums the traces within `aperture_deg` (in-ground angle from vertical) along
    its diffraction curve, weighted by obliquity cos θ / sqrt(r) and a cosine taper at the edge.
    """
    d = np.asarray(data, dtype=np.float32)
    nx, ns = d.shape
    dx = float(x_m[1] - x_m[0])
    tan_ap = math.tan(math.radians(aperture_deg))
    k_max = max(1, min(nx - 1, math.ceil(float(z_m.max()) * tan_ap / dx)))
    lags = np.arange(-k_max, k_max + 1)
    times = diffraction_times(lags * dx, z_m, v, antenna_height_m, tx_rx_offset_m)
    sample = (times + t0_ns) / dt_ns
    horiz = np.abs(lags[:, None] * dx)
    depth = np.maximum(z_m[None, :], 1e-4)
    ratio = horiz / (depth * tan_ap)
    taper = np.where(ratio <= 0.7, 1.0, 0.5 * (1.0 + np.cos(np.pi * (ratio - 0.7) / 0.3)))
    r = np.hypot(horiz, depth)
    weight = np.where((ratio <= 1.0) & (sample < ns - 1), taper * (depth / r) / np.sqrt(r), 0.0)
    padded = np.zeros((nx + 2 * k_max, ns + 1), dtype=np.float32)
    padded[k_max : k_max + nx, :ns] = d
    image = np.zeros((nx, len(z_m)), dtype=np.float32)
    for j, k in enumerate(lags):
        cols = np.flatnonzero(weight[j] > 0.0)
        if len(cols) == 0:
            continue
        s = np.clip(sample[j, cols], 0.0, ns - 1)
        i0 = s.astype(np.intp)
        frac = (s - i0).astype(np.float32)
        rows = padded[k_max + k : k_max + k + nx]
        vals = rows[:, i0] * (1.0 - frac) + rows[:, i0 + 1] * frac
        image[:, cols] += vals * weight[j, cols].astype(np.float32)
    return np.ascontiguousarray(image.T)


def stolt_migrate(
    data: NDArray[np.floating],
    x_m: FloatArray,
    dt_ns: float,
    t0_ns: float,
    z_m: FloatArray,
    v: float,
    *,
    antenna_height_m: float,
    tx_rx_offset_m: float,
) -> Float32Array:
    """Stolt f-k migration at constant velocity (exploding reflector, v/2); image (nz, nx)."""
    d = np.asarray(data, dtype=np.float64)
    nx, ns = d.shape
    dx = float(x_m[1] - x_m[0])
    # Time 0 of the ground: the transmit instant plus the air gap down and up.
    start = (t0_ns + 2.0 * antenna_height_m / C_M_PER_NS) / dt_ns
    s = start + np.arange(ns)
    valid = s < ns - 1
    i0 = np.clip(s.astype(np.intp), 0, ns - 2)
    frac = s - np.floor(s)
    shifted = np.where(valid[None, :], d[:, i0] * (1.0 - frac) + d[:, i0 + 1] * frac, 0.0)
    nx2 = 1 << math.ceil(math.log2(2 * nx))
    nt2 = 1 << math.ceil(math.log2(2 * ns))
    spectrum = np.fft.fft2(shifted, s=(nx2, nt2))
    kx = 2.0 * np.pi * np.fft.fftfreq(nx2, dx)[:, None]
    ve = v / 2.0
    dz_native = ve * dt_ns
    kz = 2.0 * np.pi * np.fft.fftfreq(nt2, dz_native)[None, :]
    d_omega = 2.0 * np.pi / (nt2 * dt_ns)
    omega = np.sign(kz) * ve * np.sqrt(kx * kx + kz * kz)
    pos = omega / d_omega
    lo = np.floor(pos)
    w = pos - lo
    inside = np.abs(omega) < np.pi / dt_ns
    i_lo = np.mod(lo.astype(np.intp), nt2)
    i_hi = np.mod(i_lo + 1, nt2)
    rows = np.arange(nx2)[:, None]
    mapped = spectrum[rows, i_lo] * (1.0 - w) + spectrum[rows, i_hi] * w
    jacobian = np.where(kz == 0.0, 0.0, ve * np.abs(kz) / np.maximum(np.sqrt(kx * kx + kz * kz), 1e-12))
    migrated = np.fft.ifft2(np.where(inside, mapped * jacobian, 0.0)).real[:nx, :ns]
    # The apex of a point at depth z lies at the zero-offset depth sqrt(z² + (offset/2)²).
    z_apparent = np.sqrt(z_m**2 + (0.5 * tx_rx_offset_m) ** 2)
    native = np.arange(ns) * dz_native
    pos_z = np.clip(z_apparent / dz_native, 0.0, ns - 1.001)
    j0 = pos_z.astype(np.intp)
    fz = pos_z - j0
    image = migrated[:, j0] * (1.0 - fz) + migrated[:, j0 + 1] * fz
    image[:, z_apparent > native[-1]] = 0.0
    return np.ascontiguousarray(image.T.astype(np.float32))


def migrate(
    data: NDArray[np.floating],
    x_m: FloatArray,
    dt_ns: float,
    t0_ns: float,
    z_m: FloatArray,
    v: float,
    *,
    method: Literal["kirchhoff", "stolt"],
    antenna_height_m: float,
    tx_rx_offset_m: float,
    aperture_deg: float = 35.0,
) -> Float32Array:
    """Migrate with the named method; image (nz, nx) on z_m."""
    if method == "stolt":
        return stolt_migrate(
            data, x_m, dt_ns, t0_ns, z_m, v, antenna_height_m=antenna_height_m, tx_rx_offset_m=tx_rx_offset_m
        )
    return kirchhoff_migrate(
        data, x_m, dt_ns, t0_ns, z_m, v,
        antenna_height_m=antenna_height_m, tx_rx_offset_m=tx_rx_offset_m, aperture_deg=aperture_deg,
    )


def envelope(image: NDArray[np.floating], axis: int = 0) -> Float32Array:
    """Instantaneous amplitude (Hilbert envelope) along an axis — depth for images, time for traces."""
    analytic = signal.hilbert(np.asarray(image, dtype=np.float64), axis=axis)
    return np.asarray(np.abs(analytic), dtype=np.float32)
