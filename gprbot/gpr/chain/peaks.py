"""Sub-sample peaks: the vertex of the parabola through a maximum and its two neighbours."""

from __future__ import annotations

from typing import Any

from numpy.typing import NDArray


def peak_offset(values: NDArray[Any], i: int) -> float:
    """Offset (cells, within ±0.5) of the parabola's vertex from the maximum at index i; 0 at an end or a plateau."""
    if i <= 0 or i >= len(values) - 1:
        return 0.0
    a, b, c = float(values[i - 1]), float(values[i]), float(values[i + 1])
    denom = a - 2.0 * b + c
    # Python floats, not numpy scalars: this runs for every pick of every hyperbola.
    return 0.0 if denom >= 0.0 else min(0.5, max(-0.5, 0.5 * (a - c) / denom))
