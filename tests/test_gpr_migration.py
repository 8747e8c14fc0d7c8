"""Migration: Kirchhoff and Stolt focus a point diffractor where it is; uniform along-track resampling."""

from __future__ import annotations

import numpy as np
import pytest

from gprbot.config import GprConfig
from gprbot.errors import InterpretationError
from gprbot.gpr.bscan import BScan, SyntheticTarget, synthetic_bscan
from gprbot.gpr.migration import depth_axis, envelope, migrate, resample_uniform
from gprbot.gpr.traveltime import velocity_from_eps

GPR = GprConfig(antenna_height_m=0.03, tx_rx_offset_m=0.08)
V = velocity_from_eps(7.0)


@pytest.mark.parametrize("method", ["kirchhoff", "stolt"])
@pytest.mark.parametrize(("x0", "depth"), [(0.55, 0.12), (0.9, 0.33)])
def test_migration_focuses_a_point_diffractor(method: str, x0: float, depth: float) -> None:
    b = synthetic_bscan(
        [SyntheticTarget(x0, depth, 0.0)], v_m_per_ns=V, centre_frequency_mhz=900.0, n_traces=150,
        spacing_m=0.01, samples=512, dt_ns=GPR.dt_ns, t0_ns=1.0, antenna_height_m=GPR.antenna_height_m,
        tx_rx_offset_m=GPR.tx_rx_offset_m, noise=0.02, rng=np.random.default_rng(0),
    )
    data, x = resample_uniform(b, 0.01)
    z = depth_axis(0.5, 0.0025)
    image = migrate(data, x, b.dt_ns, b.t0_ns, z, V, method=method,  # type: ignore[arg-type]
                    antenna_height_m=GPR.antenna_height_m, tx_rx_offset_m=GPR.tx_rx_offset_m)
    env = envelope(image)
    iz, ix = np.unravel_index(int(np.argmax(env)), env.shape)
    assert x[ix] == pytest.approx(x0, abs=0.02)
    # Stolt's air-gap correction is a static shift, exact only at the apex: allow it a little more.
    assert z[iz] == pytest.approx(depth, abs=0.02 if method == "kirchhoff" else 0.03)
    # Focused: the energy sits in a small spot, not along the hyperbola.
    spot = env[max(0, iz - 12) : iz + 13, max(0, ix - 4) : ix + 5]
    assert float((spot**2).sum()) > 0.3 * float((env**2).sum())


def test_resample_uniform_averages_bins_and_fills_gaps() -> None:
    along = np.array([0.0, 0.004, 0.011, 0.0095, 0.041])  # unordered, a stop, a gap at 2–3 cm
    positions = np.zeros((5, 3))
    positions[:, 0] = along
    data = np.repeat(np.array([[1.0], [3.0], [5.0], [7.0], [9.0]], dtype=np.float32), 4, axis=1)
    b = BScan(data, 0.1, 0.0, positions, np.zeros(5))
    out, x = resample_uniform(b, 0.01)
    np.testing.assert_allclose(x, [0.0, 0.01, 0.02, 0.03, 0.04])
    np.testing.assert_allclose(out[:, 0], [2.0, 6.0, 7.0, 8.0, 9.0])  # bins 0 and 1 averaged, 2–3 interpolated


def test_resample_refuses_a_line_shorter_than_one_cell() -> None:
    positions = np.zeros((10, 3))
    positions[:, 0] = np.linspace(0.0, 0.004, 10)
    b = BScan(np.zeros((10, 32), np.float32), 0.1, 0.0, positions, np.zeros(10))
    with pytest.raises(InterpretationError, match="too short"):
        resample_uniform(b, 0.01)
