"""Survey planner: boustrophedon lines driven forward, sideways and backward — never rotating.

The plan is a list of constant-velocity segments in the site frame (x forward, y left). Survey lines
run along ±x; between lines the robot steps sideways (+y), with a settle pause at every line end so
that the antenna is at rest when a line starts and the wheels' transients do not enter a B-scan.
The plan is for the antenna midpoint: the base follows it offset by the (fixed, never rotated) lever
arm, so the antenna — not the robot's centre — covers the requested area.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gprbot.config import SurveyConfig
from gprbot.errors import ConfigError


@dataclass(frozen=True)
class Segment:
    """One constant-velocity piece of the plan (a survey line, a sidestep or a pause)."""

    kind: str  # "line", "step" or "settle"
    t_start: float
    t_end: float
    start_xy: NDArray[np.float64]
    end_xy: NDArray[np.float64]
    line: int  # survey line index; -1 outside lines

    def position(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Planned antenna position (n, 2) at times within this segment."""
        span = max(self.t_end - self.t_start, 1e-12)
        f = np.clip((np.asarray(t) - self.t_start) / span, 0.0, 1.0)
        return np.asarray(self.start_xy + f[:, None] * (self.end_xy - self.start_xy))

    @property
    def velocity(self) -> NDArray[np.float64]:
        """Planned velocity (2,) in m/s."""
        span = max(self.t_end - self.t_start, 1e-12)
        return np.asarray((self.end_xy - self.start_xy) / span) if self.kind != "settle" else np.zeros(2)


@dataclass(frozen=True)
class SurveyPlan:
    """The whole boustrophedon plan for the antenna midpoint."""

    segments: tuple[Segment, ...]

    @property
    def duration_s(self) -> float:
        """Total planned time."""
        return self.segments[-1].t_end if self.segments else 0.0

    def lines(self) -> list[Segment]:
        """The survey-line segments in driving order."""
        return [s for s in self.segments if s.kind == "line"]

    def position(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Planned antenna position (n, 2) at any times (clamped to the plan)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = np.empty((t.size, 2))
        starts = np.array([s.t_start for s in self.segments])
        idx = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.segments) - 1)
        for i in np.unique(idx):
            sel = idx == i
            out[sel] = self.segments[i].position(t[sel])
        return out

    def velocity(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """Planned antenna velocity (n, 2) at any times."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        starts = np.array([s.t_start for s in self.segments])
        idx = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.segments) - 1)
        return np.array([self.segments[i].velocity for i in idx]).reshape(-1, 2)


def survey_region(start_xy: tuple[float, float], length_m: float, lines: int, spacing_m: float,
                  along_margin_m: float = 0.0, across_margin_m: float = 0.0) -> tuple[float, float, float, float]:
    """The area the survey lines cover, (xmin, xmax, ymin, ymax) in the site frame, widened by the margins."""
    x0, y0 = start_xy
    return (x0 - along_margin_m, x0 + length_m + along_margin_m,
            y0 - across_margin_m, y0 + (lines - 1) * spacing_m + across_margin_m)


def plan_survey(cfg: SurveyConfig) -> SurveyPlan:
    """Boustrophedon plan: line 0 forward (+x), line 1 backward, ..., stepping +y between lines."""
    if cfg.lines < 1:
        raise ConfigError(f"survey.lines: expected at least 1 line, got {cfg.lines}")
    for key in ("length_m", "speed_m_s"):
        if getattr(cfg, key) <= 0:
            raise ConfigError(f"survey.{key}: expected a positive number, got {getattr(cfg, key)}")
    if cfg.lines > 1 and cfg.spacing_m <= 0:
        raise ConfigError(f"survey.spacing_m: expected a positive number, got {cfg.spacing_m}")
    segments: list[Segment] = []
    t = 0.0
    here = np.array(cfg.start_xy_m, dtype=np.float64)

    def add(kind: str, to: NDArray[np.float64], duration: float, line: int) -> None:
        nonlocal t, here
        segments.append(Segment(kind, t, t + duration, here.copy(), to.copy(), line))
        t += duration
        here = to.copy()

    add("settle", here, cfg.settle_s, -1)
    for i in range(cfg.lines):
        direction = 1.0 if i % 2 == 0 else -1.0
        add("line", here + np.array([direction * cfg.length_m, 0.0]), cfg.length_m / cfg.speed_m_s, i)
        add("settle", here, cfg.settle_s, -1)
        if i + 1 < cfg.lines:
            add("step", here + np.array([0.0, cfg.spacing_m]), cfg.spacing_m / cfg.speed_m_s, -1)
            add("settle", here, cfg.settle_s, -1)
    return SurveyPlan(tuple(segments))
