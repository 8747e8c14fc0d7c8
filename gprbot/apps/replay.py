"""Offline reprocessing of a recorded run: run log → poses, line windows, B-scans → the survey's outputs.

Replay goes through the same code as the robot (survey assembly, `reconstruct_survey`, the run-file
writers) with the RNG seeded from the config, so the same log and models give the same PLY bytes.
A torn log replays every line that is complete in it (start and end events, poses covering the line).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gprbot import __version__, progress
from gprbot.config import Config, Vec3, build_dataclass, to_dict
from gprbot.errors import ConfigError, GprbotError
from gprbot.fusion.fuser import PoseFuser
from gprbot.fusion.snapshot import restore
from gprbot.geometry import CameraMount
from gprbot.gpr.bscan import BScan
from gprbot.infer.pipeline import reconstruct_survey, survey_steps
from gprbot.messages import (
    FusionSnapshot,
    ImuSample,
    Pose,
    RawRgbdFrame,
    RgbdFrame,
    SurveyEvent,
    Trace,
    VoMeasurement,
    WheelEncoders,
    WheelSpeeds,
)
from gprbot.outputs.run_dir import write_survey_outputs
from gprbot.reconstruct.survey_result import SurveyResult
from gprbot.runlog import RunLogWriter, make_run_header
from gprbot.runlog_reader import RunLogReader
from gprbot.survey import LineWindow, assemble_bscan, line_windows, split_by_line, start_pose

if TYPE_CHECKING:
    from gprbot.sim.scene import Scene
    from gprbot.simulated.survey import SimulatedSurvey

log = logging.getLogger(__name__)
POSE_LATENCY_S = 0.1  # a fused pose is published one reorder window after its time (fusion.fuser)


@dataclass(frozen=True)
class RecordedRun:
    """What a run log holds for the survey: traces, poses, complete line windows, and how it was read."""

    header: dict[str, Any]
    config: Config
    traces: list[Trace]
    poses: list[Pose]
    pose_source: str  # "recorded": Pose messages in the log; "continued": the daemon's filter from its snapshot
    # over the logged filter inputs (the daemon's poses to the bit); "fused": a new filter over raw sensor data
    windows: list[LineWindow]
    incomplete_lines: dict[int, str]  # line → why it is left out
    log_status: dict[str, Any]


def load_run(run_dir: Path, cfg: Config | None = None) -> RecordedRun:
    """Read a run log into the survey's inputs (cfg: override of the config recorded in the header)."""
    reader = RunLogReader(Path(run_dir))
    config = cfg or config_from_header(reader.header)
    traces: list[Trace] = []
    poses: list[Pose] = []
    sensors: list[Any] = []
    events: list[SurveyEvent] = []
    snapshot: FusionSnapshot | None = None
    after_snapshot = 0  # sensors[after_snapshot:] came after the snapshot: the filter's state holds the rest
    for record in reader:
        message = record.message
        if isinstance(message, FusionSnapshot) and snapshot is None:
            snapshot, after_snapshot = message, len(sensors)
        elif isinstance(message, Trace):
            traces.append(message)
        elif isinstance(message, Pose):
            poses.append(message)
        elif isinstance(message, SurveyEvent):
            events.append(message)
        elif isinstance(message, ImuSample | WheelSpeeds | VoMeasurement | WheelEncoders
                        | RgbdFrame | RawRgbdFrame):
            sensors.append(message)
    source = "recorded"
    if not poses and snapshot is not None:
        poses, source = continue_filter(snapshot, sensors[after_snapshot:], config), "continued"
    elif not poses and sensors:
        poses, source = fuse_poses(sensors, config), "fused"
    poses = _strictly_increasing(poses)
    windows, incomplete = windows_from_events(events, poses)
    status = reader.status()
    if reader.torn:
        log.warning("run log %s: %s", run_dir, reader.note)
    return RecordedRun(reader.header, config, traces, poses, source, windows, incomplete, status)


def config_from_header(header: dict[str, Any]) -> Config:
    """The config a run was recorded with (secrets were never logged: their defaults apply)."""
    try:
        config: Config = build_dataclass(Config, header.get("config") or {})
    except ConfigError as exc:
        raise ConfigError(f"the run log's recorded config does not load here ({exc}); pass a config to replay") from exc
    return config


def continue_filter(snapshot: FusionSnapshot, messages: Iterable[Any], cfg: Config) -> list[Pose]:
    """The daemon's poses again: its filter restored from the snapshot, fed the logged inputs in log order.

    The filter's inputs are IMU samples, encoder readings (as wheel speeds) and VO measurements; the
    log's WheelSpeeds records are the motion loop's commands, not measurements, and raw frames (if
    recorded) were already turned into the logged VO measurements. Nothing is flushed: the daemon's
    filter ran on after the log closed, so the poses end where the daemon's had reached.
    """
    fuser, queued = restore(snapshot, cfg.fusion, cfg.motors, start_pose(cfg))
    poses: list[Pose] = []
    for message in queued:
        poses.extend(fuser.push(message))
    for message in messages:
        if isinstance(message, WheelEncoders):
            poses.extend(fuser.push(message.wheel_speeds()))
        elif isinstance(message, ImuSample | VoMeasurement):
            poses.extend(fuser.push(message))
    return poses


def fuse_poses(messages: Iterable[Any], cfg: Config) -> list[Pose]:
    """Poses from raw IMU, wheel and VO data (RGB-D frames run through VO when no VO was recorded)."""
    items = list(messages)
    have_vo = any(isinstance(m, VoMeasurement) for m in items)
    x, y, yaw = start_pose(cfg)  # where the daemon's filter starts the base
    fuser = PoseFuser(cfg.fusion, cfg.motors, initial_position=(x, y, 0.0), initial_yaw_rad=yaw)
    odometry = None
    poses: list[Pose] = []
    for message in items:
        if isinstance(message, WheelEncoders):
            message = message.wheel_speeds()
        if isinstance(message, RawRgbdFrame):
            depth = message.depth.astype(np.float32) * np.float32(message.depth_scale)
            message = RgbdFrame(message.t, message.color, depth, message.fx, message.fy, message.cx, message.cy)
        if isinstance(message, RgbdFrame):
            if have_vo:
                continue
            if odometry is None:
                from gprbot.fusion.vo import RgbdOdometry  # OpenCV: only when frames need it
                from gprbot.fusion.vo_map import MapConfig

                mount = CameraMount(cfg.mount.camera_position_m, cfg.mount.camera_pitch_down_deg)
                odometry = RgbdOdometry(mount, map_config=MapConfig(slots=cfg.fusion.vo_map_slots))
            for measurement in odometry.process(message):
                poses.extend(fuser.push(measurement))
            continue
        poses.extend(fuser.push(message))
    poses.extend(fuser.flush())
    return poses


def windows_from_events(events: Iterable[SurveyEvent], poses: list[Pose]) -> tuple[list[LineWindow], dict[int, str]]:
    """Complete line windows (a start and an end, poses covering both) and why the others are left out."""
    started: dict[int, float] = {}
    windows: list[LineWindow] = []
    incomplete: dict[int, str] = {}
    for event in events:
        if event.kind == "line_start":
            started[event.line] = event.t
        elif event.kind == "line_end" and event.line in started:
            windows.append(LineWindow(event.line, started.pop(event.line), event.t))
    incomplete.update({line: "the log holds its start but not its end" for line in started})
    covered = (poses[0].t, poses[-1].t) if len(poses) >= 2 else (np.inf, -np.inf)
    complete = []
    for w in windows:
        if covered[0] <= w.t_start and w.t_end <= covered[1]:
            complete.append(w)
        else:
            incomplete[w.line] = f"poses cover [{covered[0]:.2f}, {covered[1]:.2f}] s, not the whole line"
    return complete, incomplete


def survey_bscans(run: RecordedRun) -> dict[int, BScan]:
    """One B-scan per complete line, traces tagged with the interpolated poses."""
    lever = run.config.mount.antenna_lever_arm_m
    by_line = split_by_line(run.traces, run.windows)
    return {line: assemble_bscan(traces, run.poses, lever) for line, traces in by_line.items() if traces}


def with_known_tops(cfg: Config, tops: Sequence[Vec3]) -> Config:
    """The config with the velocity calibrated on these known tops (x, y, depth of the top; site frame, m),
    eps_r cleared: a known cover is what the inspector measured on this slab."""
    return replace(cfg, gpr=replace(cfg.gpr, eps_r=None, known_tops=tuple(tops)))


def replay_run(run_dir: Path, out_dir: Path, cfg: Config | None = None,
               known_tops: Sequence[Vec3] = ()) -> SurveyResult:
    """Reprocess a recorded run into out_dir (PLYs, pipes.json, PNGs, summary.json with the log's state);
    `known_tops` calibrate its velocity (`with_known_tops`)."""
    with progress.bar(None, f"{Path(run_dir).name}: reading the run log") as steps:

        def step(what: str) -> None:
            steps.set_description(f"{Path(run_dir).name}: {what}")
            steps.update()

        run = load_run(run_dir, cfg)
        if known_tops:
            run = replace(run, config=with_known_tops(run.config, known_tops))
        bscans = survey_bscans(run)
        if not bscans:
            raise GprbotError(f"{run_dir}: no complete survey line in the run log "
                              f"({run.log_status['note'] or 'no lines'})")
        steps.total = survey_steps(len(bscans)) + 2
        step("read the log")
        result = reconstruct_survey(bscans, run.config, np.random.default_rng(run.config.reconstruction_seed), step)
        steps.set_description(f"{Path(run_dir).name}: writing the results")
        positions = np.concatenate([b.positions for b in bscans.values()])
        lo, hi = positions.min(axis=0) - 0.2, positions.max(axis=0) + 0.2
        meta = {
            "run": Path(run_dir).name,
            "gprbot_version": __version__,
            "replayed_from": {k: run.header.get(k) for k in ("gprbot_version", "git_commit", "created", "devices")},
            "pose_source": run.pose_source,
            "run_log": run.log_status,
            "incomplete_lines": {str(k): v for k, v in sorted(run.incomplete_lines.items())},
            "config": to_dict(run.config),
        }
        write_survey_outputs(Path(out_dir), result, meta, (lo[0], hi[0], lo[1], hi[1]), raw_lines=bscans)
        step("written")
    return result


def survey_messages(sim: Any) -> list[tuple[float, Any]]:
    """A simulated survey's messages in arrival order (receive time, message): traces, poses, line events."""
    timed: list[tuple[float, int, Any]] = [(tr.t, 1, tr) for tr in sim.traces]
    timed += [(p.t + POSE_LATENCY_S, 0, p) for p in sim.trajectory.estimated_poses]
    for w in line_windows(sim.plan):
        timed += [(w.t_start, 2, SurveyEvent(w.t_start, "line_start", w.line)),
                  (w.t_end, 2, SurveyEvent(w.t_end, "line_end", w.line))]
    timed.sort(key=lambda item: (item[0], item[1]))
    return [(t, m) for t, _, m in timed]


def record_simulated_survey(cfg: Config, scene: Scene, run_dir: Path, created_wall_s: float = 0.0,
                            segment_bytes: int = 64 * 1024 * 1024) -> SimulatedSurvey:
    """Simulate a survey and record it as the daemon would: traces, estimated poses, line events."""
    from gprbot.simulated.survey import simulate_survey

    sim = simulate_survey(cfg, scene)
    timed = survey_messages(sim)
    header = make_run_header(cfg, created_wall_s, {"gpr": "sim", "realsense": "sim", "motors": "sim"}, scene=scene.name)
    writer = RunLogWriter(run_dir, header, segment_bytes=segment_bytes)
    for t_received, message in timed:
        writer.append(message, t_received)
    writer.close({"traces": len(sim.traces), "lines": len(sim.plan.lines())})
    return sim


def _strictly_increasing(poses: list[Pose]) -> list[Pose]:
    """Poses sorted by time with repeated stamps dropped (interpolation needs increasing times)."""
    out: list[Pose] = []
    for pose in sorted(poses, key=lambda p: p.t):
        if not out or pose.t > out[-1].t:
            out.append(pose)
    return out
