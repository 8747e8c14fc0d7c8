"""Survey bookkeeping: which traces belong to which line, and tagging each trace with its pose."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gprbot.config import Config
from gprbot.errors import InterpretationError
from gprbot.fusion.interpolate import interpolate_poses
from gprbot.geometry import antenna_positions
from gprbot.gpr.bscan import BScan
from gprbot.messages import Pose, Trace
from gprbot.motion.planner import SurveyPlan


def start_pose(cfg: Config) -> tuple[float, float, float]:
    """Where the base starts (x, y, yaw): the antenna midpoint over the survey's start point, heading +x."""
    lever = cfg.mount.antenna_lever_arm_m
    x0, y0 = cfg.survey.start_xy_m
    return (x0 - lever[0], y0 - lever[1], 0.0)


@dataclass(frozen=True)
class LineWindow:
    """The time span during which survey line `line` was driven."""

    line: int
    t_start: float
    t_end: float


def line_windows(plan: SurveyPlan, t_offset: float = 0.0) -> list[LineWindow]:
    """The line windows of a plan, shifted to the clock on which it was executed."""
    return [LineWindow(s.line, s.t_start + t_offset, s.t_end + t_offset) for s in plan.lines()]


def assemble_bscan(
    traces: Sequence[Trace], poses: Sequence[Pose], lever_arm: tuple[float, float, float]
) -> BScan:
    """One line's traces as a B-scan whose trace positions come from the interpolated poses."""
    if not traces:
        raise InterpretationError("a survey line has no traces; check that the GPR was acquiring")
    dt = {tr.dt_ns for tr in traces}
    lengths = {tr.samples.size for tr in traces}
    if len(dt) != 1 or len(lengths) != 1:
        raise InterpretationError(
            f"a line mixes GPR settings (dt {sorted(dt)} ns, samples {sorted(lengths)}); "
            "changing the GPR setup mid-line is not supported — restart the line"
        )
    times = np.array([tr.t for tr in traces])
    tagged = interpolate_poses(poses, times)
    return BScan(
        data=np.stack([tr.samples for tr in traces]).astype(np.float32),
        dt_ns=traces[0].dt_ns,
        t0_ns=traces[0].t0_ns,
        positions=antenna_positions(tagged, lever_arm),
        times=times,
        position_std_m=antenna_position_std(tagged, lever_arm),
    )


def antenna_position_std(poses: Sequence[Pose], lever_arm: tuple[float, float, float]) -> np.ndarray:
    """1σ of each antenna position: the base's, and the heading's swing of the lever arm, in quadrature."""
    swing = float(np.hypot(lever_arm[0], lever_arm[1]))
    return np.array([np.hypot(p.position_std_m, swing * p.yaw_std_rad) for p in poses])


def split_by_line(traces: Sequence[Trace], windows: Sequence[LineWindow]) -> dict[int, list[Trace]]:
    """Group traces by the line window they fall in; traces between lines are dropped."""
    out: dict[int, list[Trace]] = {w.line: [] for w in windows}
    for tr in traces:
        for w in windows:
            if w.t_start <= tr.t <= w.t_end:
                out[w.line].append(tr)
                break
    return out
