"""Replay: a recorded simulated survey reprocesses to the direct pipeline's result, bit for bit."""

from __future__ import annotations

import dataclasses
import io
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gprbot.apps.replay import fuse_poses, load_run, record_simulated_survey, replay_run, windows_from_events
from gprbot.config import load_config
from gprbot.errors import GprbotError
from gprbot.fusion.fuser import PoseFuser
from gprbot.fusion.snapshot import restore, take_snapshot
from gprbot.infer.pipeline import reconstruct_survey
from gprbot.messages import ImuSample, Pose, SurveyEvent, WheelSpeeds
from gprbot.runlog import segment_path
from gprbot.runlog_reader import RunLogReader
from gprbot.sim.scene import load_scene
from gprbot.survey import assemble_bscan, line_windows, split_by_line, start_pose


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A 3-line survey recorded into a run log (small segments), and its direct reconstruction."""
    base = load_config()
    cfg = dataclasses.replace(base, survey=dataclasses.replace(base.survey, lines=3, length_m=1.0))
    run_dir = tmp_path_factory.mktemp("replay") / "run-0001"
    sim = record_simulated_survey(cfg, load_scene("paper_slab"), run_dir, 1.7e9, segment_bytes=256 * 1024)
    by_line = split_by_line(sim.traces, line_windows(sim.plan))
    lever = cfg.mount.antenna_lever_arm_m
    bscans = {line: assemble_bscan(tr, sim.trajectory.estimated_poses, lever) for line, tr in by_line.items()}
    direct = reconstruct_survey(bscans, cfg, np.random.default_rng(cfg.reconstruction_seed))
    return {"cfg": cfg, "run_dir": run_dir, "sim": sim, "direct": direct}


def test_replay_reproduces_the_direct_pipeline_and_identical_ply_bytes(recorded: dict[str, Any],
                                                                       tmp_path: Path) -> None:
    run_dir, direct = recorded["run_dir"], recorded["direct"]
    assert len(list(run_dir.glob("log-*.msgpack"))) > 3  # the survey spans several segments
    run = load_run(run_dir)
    assert run.config == recorded["cfg"] and run.pose_source == "recorded" and not run.incomplete_lines
    assert [(w.line, w.t_start, w.t_end) for w in run.windows] == [
        (w.line, w.t_start, w.t_end) for w in line_windows(recorded["sim"].plan)]

    first = replay_run(run_dir, tmp_path / "a")
    second = replay_run(run_dir, tmp_path / "b")
    assert first.velocity_m_per_ns == direct.velocity_m_per_ns
    assert np.array_equal(first.sparse, direct.sparse)
    assert np.array_equal(first.reconstruction.dense, direct.reconstruction.dense)
    assert len(first.reconstruction.pipes) == len(direct.reconstruction.pipes) > 0
    for got, want in zip(first.reconstruction.pipes, direct.reconstruction.pipes, strict=True):
        assert np.array_equal(got.axis, want.axis) and got.diameter_m == want.diameter_m
    for name in ("sparse.ply", "dense.ply"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert np.array_equal(second.reconstruction.dense, first.reconstruction.dense)
    pipes = json.loads((tmp_path / "a" / "pipes.json").read_text())
    assert len(pipes["pipes"]) == len(direct.reconstruction.pipes)
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["run_log"]["ended"] and not summary["run_log"]["torn"]
    assert summary["replayed_from"]["created"] == 1.7e9


def test_torn_log_replays_the_complete_lines(recorded: dict[str, Any], tmp_path: Path) -> None:
    source = recorded["run_dir"]
    torn = tmp_path / "torn"
    shutil.copytree(source, torn)
    records = list(RunLogReader(source))
    start_2 = next(r for r in records if r.message == SurveyEvent(r.message.t, "line_start", 2))
    after = next(r for r in records if r.t_received > start_2.t_received + 2.0)
    for later in sorted(torn.glob("log-*.msgpack"))[after.segment + 1:]:
        later.unlink()
    # kill -9 mid-write: cut at a random byte between 2 s into line 2 and the end of that segment
    path = segment_path(torn, after.segment)
    size = path.stat().st_size
    cut = int(np.random.default_rng(7).integers(after.offset + 1, size))
    cut += cut in {r.offset for r in records if r.segment == after.segment}  # land inside a record
    path.write_bytes(path.read_bytes()[:cut])

    run = load_run(torn)
    assert run.log_status["torn"] and not run.log_status["ended"]
    assert [w.line for w in run.windows] == [0, 1] and 2 in run.incomplete_lines
    result = replay_run(torn, tmp_path / "out")
    assert [lr.line for lr in result.lines] == [0, 1]
    direct_lines = {lr.line: lr for lr in recorded["direct"].lines}
    for lr in result.lines:  # the same traces and poses: the same processed B-scan
        assert np.array_equal(lr.bscan.data, direct_lines[lr.line].bscan.data)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["run_log"]["torn"] and not summary["run_log"]["ended"]
    assert "2" in summary["incomplete_lines"]


def test_line_windows_need_both_events_and_pose_coverage() -> None:
    poses = [Pose(t, np.zeros(3)) for t in (0.0, 5.0, 10.0)]
    events = [SurveyEvent(1.0, "line_start", 0), SurveyEvent(4.0, "line_end", 0),
              SurveyEvent(6.0, "line_start", 1), SurveyEvent(12.0, "line_end", 1),
              SurveyEvent(13.0, "line_start", 2), SurveyEvent(14.0, "abort")]
    windows, incomplete = windows_from_events(events, poses)
    assert [(w.line, w.t_start, w.t_end) for w in windows] == [(0, 1.0, 4.0)]
    assert set(incomplete) == {1, 2} and "poses cover" in incomplete[1] and "end" in incomplete[2]


def test_poses_are_fused_from_raw_sensors_when_none_were_recorded() -> None:
    cfg = load_config()
    gravity = np.array([0.0, 0.0, 9.81])
    messages: list[Any] = []
    for k in range(300):  # 1.5 s at rest: IMU at 200 Hz, wheels at 50 Hz
        t = 0.005 * k
        messages.append(ImuSample(t, np.zeros(3), gravity.copy()))
        if k % 4 == 0:
            messages.append(WheelSpeeds(t, np.zeros(3)))
    poses = fuse_poses(messages, cfg)
    assert len(poses) > 50
    # At rest where the daemon's filter starts the base: the antenna over the survey's start point.
    x, y, _ = start_pose(cfg)
    assert max(float(np.abs(p.position - [x, y, 0.0]).max()) for p in poses) < 1e-3


def test_a_snapshot_taken_before_the_filter_initialised_restores_its_start_pose() -> None:
    # A run log opened on a daemon just started holds a snapshot of a filter still collecting its rest
    # samples; restored without its start pose it initialised at the origin: every replayed pipe was a lever
    # arm (25 cm) off the daemon's own.
    cfg = load_config()
    x, y, yaw = start_pose(cfg)
    live = PoseFuser(cfg.fusion, cfg.motors, initial_position=(x, y, 0.0), initial_yaw_rad=yaw)
    snapshot = take_snapshot(0.0, live)
    gravity = np.array([0.0, 0.0, 9.81])
    rest: list[Any] = []
    for k in range(300):  # 1.5 s at rest: IMU at 200 Hz, wheels at 50 Hz
        rest.append(ImuSample(0.005 * k, np.zeros(3), gravity.copy()))
        if k % 4 == 0:
            rest.append(WheelSpeeds(0.005 * k, np.zeros(3)))
    older = dataclasses.replace(snapshot, arrays=_without(snapshot.arrays, "initial_pose"))
    for restored in (restore(snapshot, cfg.fusion, cfg.motors)[0],  # its own arrays say where
                     restore(older, cfg.fusion, cfg.motors, (x, y, yaw))[0]):  # an older one: the caller's pose
        poses = [p for m in rest for p in restored.push(m)]
        assert poses and max(float(np.abs(p.position - [x, y, 0.0]).max()) for p in poses) < 1e-3


def _without(arrays: bytes, name: str) -> bytes:
    """An npz archive less one of its arrays."""
    with np.load(io.BytesIO(arrays)) as data:
        kept = {k: data[k] for k in data.files if k != name}
    buffer = io.BytesIO()
    np.savez(buffer, **kept)
    return buffer.getvalue()


def test_a_log_without_complete_lines_is_a_clear_error(tmp_path: Path, recorded: dict[str, Any]) -> None:
    source = recorded["run_dir"]
    shutil.copytree(source, tmp_path / "run")
    for later in sorted((tmp_path / "run").glob("log-*.msgpack"))[1:]:
        later.unlink()
    path = segment_path(tmp_path / "run", 0)
    path.write_bytes(path.read_bytes()[:50_000])
    with pytest.raises(GprbotError, match="no complete survey line"):
        replay_run(tmp_path / "run", tmp_path / "out")
