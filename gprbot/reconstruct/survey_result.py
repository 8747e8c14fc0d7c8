"""What a survey's interpretation and reconstruction produced: per line and for the whole survey."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from gprbot.gpr.bscan import BScan
from gprbot.gpr.interpret import CrossSection
from gprbot.reconstruct.completion import Reconstruction
from gprbot.reconstruct.register import SliceCloud


@dataclass(frozen=True)
class LineResult:
    """One survey line: its processed B-scan, its cross-section and the slice registered in 3D."""

    line: int
    bscan: BScan
    section: CrossSection
    slice: SliceCloud


@dataclass(frozen=True)
class SurveyResult:
    """The interpretation and reconstruction of a whole survey."""

    lines: tuple[LineResult, ...]
    velocity_m_per_ns: float
    velocity_estimated: bool
    sparse: NDArray[np.float64]
    reconstruction: Reconstruction
    timings_s: dict[str, float] = field(default_factory=dict)
    skipped_lines: dict[int, str] = field(default_factory=dict)  # line → why it could not be interpreted
    velocity_method: str = ""  # how the velocity was found, in words ("": as velocity_estimated says)
