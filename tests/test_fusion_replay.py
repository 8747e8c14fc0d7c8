"""The daemon's poses again from its run log: the filter's snapshot, then its logged inputs (issue 14)."""

from __future__ import annotations

import asyncio
import dataclasses
import time
from pathlib import Path

import numpy as np
import pytest

from gprbot.apps.replay import load_run
from gprbot.config import MotorsConfig, load_config
from gprbot.daemon import serve
from gprbot.errors import GprbotError
from gprbot.fusion.fuser import PoseFuser
from gprbot.fusion.snapshot import restore, take_snapshot
from gprbot.messages import FusionSnapshot, Pose, VoHealth, VoMeasurement, decode, encode
from gprbot.robot import survey_runner
from gprbot.robot.runtime import RobotRuntime
from gprbot.runlog_reader import RunLogReader
from gprbot.sdnotify import SdNotifier
from gprbot.sim.motion_truth import straight_ground_truth
from tests.test_ekf import sensor_messages, start_of


def same(a: list[Pose], b: list[Pose]) -> bool:
    """Bit for bit: the same stamps, positions and orientations."""
    return len(a) == len(b) and all(
        x.t == y.t and np.array_equal(x.position, y.position) and np.array_equal(x.orientation, y.orientation)
        for x, y in zip(a, b, strict=True))


def test_a_snapshot_through_the_codec_continues_the_filter_to_the_bit() -> None:
    truth = straight_ground_truth(8.0, (0.1, 0.0), seed=3)
    messages = sensor_messages(truth)
    position, yaw = start_of(truth)
    whole = PoseFuser(initial_position=position, initial_yaw_rad=yaw)
    expected = [p for m in messages for p in whole.push(m)]
    first = PoseFuser(initial_position=position, initial_yaw_rad=yaw)
    half = len(messages) // 2
    before = [p for m in messages[:half] for p in first.push(m)]
    pending = messages[half:half + 3]  # submitted to the fusion task, not yet pushed when the log opened
    snapshot = decode(encode(take_snapshot(4.0, first, pending)))
    assert isinstance(snapshot, FusionSnapshot) and len(snapshot.heap) > 0  # the reorder buffer holds messages
    second, queued = restore(snapshot, first.config, MotorsConfig())
    after = [p for m in [*queued, *messages[half + 3:]] for p in second.push(m)]
    assert len(before) > 100 and len(after) > 100
    assert same(before + after, expected)
    assert second.stats == whole.stats


async def test_replay_reproduces_the_daemons_poses_to_the_bit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def slow_prune(*args: object) -> list[object]:
        time.sleep(0.5)  # a loaded CI machine: sensor messages arrive while old runs are pruned
        return []

    monkeypatch.setattr(survey_runner, "prune_runs", slow_prune)
    cfg = load_config()
    survey = dataclasses.replace(cfg.survey, lines=1, length_m=0.3, speed_m_s=0.2, settle_s=0.3)
    cfg = dataclasses.replace(cfg, survey=survey, runs_dir=str(tmp_path / "runs"))
    stop = asyncio.Event()
    started: list[RobotRuntime] = []
    task = asyncio.create_task(serve(cfg, shell_port=0, stop=stop, use_worker=False, notifier=SdNotifier(environ={}),
                                     on_ready=started.append))  # type: ignore[arg-type]
    try:
        async with asyncio.timeout(100):  # a loaded machine: the per-test limit is 120 s
            while not started or not started[0].fusion.ready:
                await asyncio.sleep(0.05)
            runtime = started[0]
            run = runtime.survey.start(survey)
            while run.state not in ("done", "aborted", "failed"):
                await asyncio.sleep(0.1)
        daemon_poses = list(runtime.fusion.fuser.history)
        vo_status = runtime.vo.health()
    finally:
        stop.set()
        async with asyncio.timeout(30):
            await task
    replayed = load_run(run.run_dir)
    assert replayed.pose_source == "continued"
    assert len(replayed.poses) > 100
    t0, t1 = replayed.poses[0].t, replayed.poses[-1].t
    assert same(replayed.poses, [p for p in daemon_poses if t0 <= p.t <= t1])
    records = [r.message for r in RunLogReader(run.run_dir)]
    assert any(isinstance(m, VoMeasurement) for m in records)  # (a starved VO may close no keyframe in 1.5 s)
    assert any(isinstance(m, VoHealth) for m in records)
    assert vo_status.frames > 0 and vo_status.state != "starting"


def test_an_unreadable_snapshot_says_what_replay_does_instead() -> None:
    fuser = PoseFuser()
    snapshot = take_snapshot(0.0, fuser)
    broken = dataclasses.replace(snapshot, arrays=snapshot.arrays[:40])
    with pytest.raises(GprbotError, match="re-runs the filter from the log's start"):
        restore(broken, fuser.config, MotorsConfig())
