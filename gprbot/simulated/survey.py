"""A simulated survey: the GPR traces the antenna records while the robot drives the plan."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from gprbot.config import Config, FusionConfig, MotorsConfig, SurveyConfig
from gprbot.messages import Trace
from gprbot.motion.planner import SurveyPlan, plan_survey
from gprbot.sim.forward import simulate_bscan
from gprbot.sim.scene import Scene
from gprbot.sim.trajectory import SimulatedTrajectory, simulate_trajectory
from gprbot.simulated.sensor_runs import fused_trajectory


@dataclass(frozen=True)
class SimulatedSurvey:
    """Everything a simulated survey produced: the plan, both trajectories and the traces."""

    plan: SurveyPlan
    trajectory: SimulatedTrajectory
    traces: tuple[Trace, ...]


@functools.lru_cache(maxsize=2)
def _fused(
    survey: SurveyConfig, lever_arm: tuple[float, float, float], motors: MotorsConfig, fusion: FusionConfig, seed: int
) -> SimulatedTrajectory:
    # The robot's path does not depend on what lies under the slab: surveys of several scenes with the
    # same plan share one fused trajectory (rendering and VO are most of a simulated survey's time).
    return fused_trajectory(plan_survey(survey), lever_arm, motors, fusion, seed)


def simulate_survey(cfg: Config, scene: Scene) -> SimulatedSurvey:
    """Drive the configured survey over `scene` and record a trace at the GPR's trigger rate."""
    plan = plan_survey(cfg.survey)
    if cfg.sim.poses == "fused":
        trajectory = _fused(cfg.survey, cfg.mount.antenna_lever_arm_m, cfg.motors, cfg.fusion, cfg.sim.seed)
    else:
        trajectory = simulate_trajectory(plan, cfg.mount.antenna_lever_arm_m, cfg.pose_noise)
    rng = np.random.default_rng(cfg.sim.seed)
    traces: list[Trace] = []
    number = 0
    for seg in plan.lines():
        t = np.arange(seg.t_start, seg.t_end, 1.0 / cfg.survey.trace_rate_hz)
        data = simulate_bscan(scene, trajectory.true_antenna_xy(t), cfg.gpr, rng)
        for ti, samples in zip(t, data, strict=True):
            traces.append(Trace(float(ti), number, samples, cfg.gpr.dt_ns, cfg.gpr.pre_trigger_ns))
            number += 1
    return SimulatedSurvey(plan, trajectory, tuple(traces))
