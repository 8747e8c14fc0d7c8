"""Simulated runs: sensor streams from a ground truth, through the robot's pose filter and the baselines.

Messages reach the filter in the order they would on the robot — by arrival time, not sensor time:
IMU 2 ms after sampling, wheel speeds 5 ms, VO 40 ms after its frame (a VO result stamped with an
earlier frame, on loss of tracking, arrives later still) — so the reorder buffer does real work.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from gprbot.config import FusionConfig, MotorsConfig
from gprbot.fusion.baselines import imu_dead_reckoning, vo_only, wheel_only
from gprbot.fusion.fuser import FusionStats, PoseFuser
from gprbot.fusion.so3 import yaw_of
from gprbot.fusion.vo import RgbdOdometry
from gprbot.fusion.vo_map import MapConfig
from gprbot.messages import ImuSample, Pose, VoMeasurement, WheelSpeeds
from gprbot.motion.planner import SurveyPlan
from gprbot.sim.camera import CameraModel, FloorCamera
from gprbot.sim.encoders import EncoderRecording, simulate_encoders
from gprbot.sim.floor_texture import FloorSpec
from gprbot.sim.imu import ImuRecording, simulate_imu
from gprbot.sim.motion_truth import GroundTruth, survey_ground_truth
from gprbot.sim.trajectory import SimulatedTrajectory

IMU_LATENCY_S, WHEEL_LATENCY_S, VO_LATENCY_S = 0.002, 0.005, 0.040


@dataclass(frozen=True)
class SimulatedRun:
    """Ground truth, sensor recordings and the VO output of one simulated run."""

    name: str
    truth: GroundTruth
    imu: ImuRecording
    wheels: EncoderRecording
    vo: tuple[tuple[float, VoMeasurement], ...]  # (arrival time, measurement)
    frames: int
    vo_lost_frames: int
    vo_ms_per_frame: float
    render_ms_per_frame: float


def simulate_run(name: str, truth: GroundTruth, seed: int = 0, camera: CameraModel | None = None,
                 floor: FloorSpec | None = None, motors: MotorsConfig | None = None,
                 map_slots: int = MapConfig.slots) -> SimulatedRun:
    """Sample every sensor over the trajectory and run VO (with `map_slots` map keyframes) on the rendered frames."""
    imu = simulate_imu(truth, seed=seed)
    wheels = simulate_encoders(truth, motors, seed=seed)
    cam = FloorCamera(floor, camera, seed=seed)
    vo = RgbdOdometry(cam.model.mount, map_config=MapConfig(slots=map_slots))
    out: list[tuple[float, VoMeasurement]] = []
    render_s = vo_s = 0.0
    frames = lost = 0
    clock = time.perf_counter
    t = truth.t_start
    period = 1.0 / cam.model.fps
    while t < truth.t_end - cam.model.exposure_s:
        start = clock()
        frame = cam.render_truth(t, truth)
        middle = clock()
        out.extend((t + VO_LATENCY_S, m) for m in vo.process(frame))
        render_s, vo_s = render_s + middle - start, vo_s + clock() - middle
        frames += 1
        lost += vo.keyframe is None
        t += period
    return SimulatedRun(name, truth, imu, wheels, tuple(out), frames, lost, 1e3 * vo_s / max(frames, 1),
                        1e3 * render_s / max(frames, 1))


@dataclass(frozen=True)
class Estimates:
    """Every estimator's poses on one run, and the filter's bookkeeping."""

    fused: list[Pose]
    vo: list[Pose]
    wheels: list[Pose]
    imu: list[Pose]
    stats: FusionStats
    filter_s: float


def arrival_order(run: SimulatedRun) -> list[ImuSample | WheelSpeeds | VoMeasurement]:
    """All messages in the order they reach the filter."""
    timed: list[tuple[float, int, ImuSample | WheelSpeeds | VoMeasurement]] = []
    timed += [(m.t + IMU_LATENCY_S, 0, m) for m in run.imu.messages()]
    timed += [(m.t + WHEEL_LATENCY_S, 1, m) for m in run.wheels.messages()]
    timed += [(arrival, 2, m) for arrival, m in run.vo]
    timed.sort(key=lambda item: (item[0], item[1]))
    return [m for _, _, m in timed]


def run_estimators(
    run: SimulatedRun, config: FusionConfig | None = None, motors: MotorsConfig | None = None
) -> Estimates:
    """The fused filter and the three single-source baselines, all from the known start pose."""
    config = config or FusionConfig()
    motors = motors or MotorsConfig()
    t0 = np.array([run.truth.t_start])
    start, yaw = run.truth.position(t0)[0], yaw_of(run.truth.rotation(t0)[0])
    fuser = PoseFuser(config, motors, (float(start[0]), float(start[1]), float(start[2])), yaw)
    began = time.perf_counter()
    fused: list[Pose] = []
    for message in arrival_order(run):
        fused.extend(fuser.push(message))
    fused.extend(fuser.flush())
    filter_s = time.perf_counter() - began
    vo_messages = [m for _, m in run.vo]
    return Estimates(
        fused=fused,
        vo=vo_only(vo_messages, start, yaw, run.truth.t_start),
        wheels=wheel_only(run.wheels.messages(), motors, start, yaw),
        imu=imu_dead_reckoning(run.imu.messages(), start, yaw, config.init_duration_s),
        stats=fuser.stats,
        filter_s=filter_s,
    )


def fused_trajectory(
    plan: SurveyPlan, lever_arm: tuple[float, float, float], motors: MotorsConfig, fusion: FusionConfig, seed: int
) -> SimulatedTrajectory:
    """The base driving `plan` with real dynamics, and the pose filter's estimate from simulated sensors.

    The estimate comes from the same code the robot runs: simulated BMI055 IMU, slipping wheel encoders
    and a rendered floor seen by the D435i, through visual odometry and the loosely coupled filter.
    """
    truth = survey_ground_truth(plan, (lever_arm[0], lever_arm[1]), seed=seed)
    run = simulate_run("survey", truth, seed=seed, motors=motors, map_slots=fusion.vo_map_slots)
    t0 = np.array([truth.t_start])
    start = truth.position(t0)[0]
    start_xyz = (float(start[0]), float(start[1]), float(start[2]))
    fuser = PoseFuser(fusion, motors, start_xyz, yaw_of(truth.rotation(t0)[0]))
    estimated: list[Pose] = []
    for message in arrival_order(run):
        estimated.extend(fuser.push(message))
    estimated.extend(fuser.flush())
    times = np.array([p.t for p in estimated])
    arm = np.asarray(lever_arm, dtype=np.float64)
    return SimulatedTrajectory(times, tuple(truth.poses(times)), tuple(estimated), arm)
