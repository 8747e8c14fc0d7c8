"""The source wavelet, once: the simulator's forward model and the interpretation's models share it."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray


def ricker(t_ns: NDArray[np.float64], centre_frequency_mhz: float) -> NDArray[np.float64]:
    """Ricker (Mexican-hat) wavelet with peak frequency centre_frequency_mhz, peak 1 at t = 0 ns."""
    a = (math.pi * centre_frequency_mhz * 1e-3 * np.asarray(t_ns, dtype=np.float64)) ** 2
    return np.asarray((1.0 - 2.0 * a) * np.exp(-a))
