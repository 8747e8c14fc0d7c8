"""Per-trace pose uncertainty: from the filter's covariance to each trace, each slice and each pipe (issue 14)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from gprbot.fusion.fuser import PoseFuser
from gprbot.messages import Pose, Trace
from gprbot.outputs.pipes_json import read_pipes_json, write_pipes_json
from gprbot.reconstruct.completion import Reconstruction, geometric_completion, pose_confidence
from gprbot.sim.motion_truth import straight_ground_truth
from gprbot.survey import assemble_bscan
from tests.test_completion import CFG, make_slices, straight
from tests.test_ekf import run, sensor_messages, start_of


def test_the_filters_position_std_grows_without_vo_and_shrinks_with_it() -> None:
    truth = straight_ground_truth(20.0, (0.1, 0.0), seed=5)
    gap = (6.0, 14.0)
    position, yaw = start_of(truth)
    poses = run(PoseFuser(initial_position=position, initial_yaw_rad=yaw), sensor_messages(truth, gap=gap))
    t = np.array([p.t for p in poses])
    std = np.array([p.position_std_m for p in poses])
    yaw_std = np.array([p.yaw_std_rad for p in poses])
    assert np.all(std > 0.0) and np.all(yaw_std > 0.0)
    before, late_in_gap, after = (std[np.searchsorted(t, s)] for s in (gap[0], gap[1] - 0.1, gap[1] + 3.0))
    assert late_in_gap > 2.0 * before  # IMU + wheels alone: the uncertainty grows over the gap...
    assert after < late_in_gap  # ...and VO, back, brings it down (relative motion cannot undo all of it)
    # Losing VO and finding it again moves no pose by a jump: beyond what the robot drove in each 10 ms
    # step, no correction exceeds 3σ of the filter's own uncertainty of the moment (VO's return: ~1 mm).
    steps = np.linalg.norm(np.diff(np.stack([p.position[:2] for p in poses]), axis=0), axis=1)
    true_steps = np.linalg.norm(np.diff(truth.position(t)[:, :2], axis=0), axis=1)
    assert np.all(np.abs(steps - true_steps) < 3.0 * std[1:])
    # Errors and uncertainty agree in size: the error stays within a few σ.
    error = np.linalg.norm(np.stack([p.position[:2] for p in poses]) - truth.position(t)[:, :2], axis=1)
    assert np.all(error[t > 2.0] < 4.0 * std[t > 2.0] + 1e-3)


def test_each_trace_carries_its_antenna_position_std() -> None:
    poses = [Pose(0.0, np.zeros(3), position_std_m=0.001, yaw_std_rad=0.0),
             Pose(1.0, np.array([0.1, 0.0, 0.0]), position_std_m=0.003, yaw_std_rad=0.01)]
    traces = [Trace(t, i, np.zeros(8, dtype=np.float32), 0.1) for i, t in enumerate((0.0, 0.5, 1.0))]
    bscan = assemble_bscan(traces, poses, (0.25, 0.0, 0.0))
    assert bscan.position_std_m is not None
    # The heading's σ swings the 0.25 m lever arm: 2.5 mm at 0.01 rad, in quadrature with the base's.
    assert bscan.position_std_m == pytest.approx([0.001, np.hypot(0.002, 0.00125), np.hypot(0.003, 0.0025)])


def test_a_pipe_from_poorly_placed_slices_is_less_confident(tmp_path: Path) -> None:
    rods = [straight(0.6, 0.45, 0.2, 90, 0.025)]
    sharp = geometric_completion(make_slices(rods), CFG, np.random.default_rng(0))
    blurred_slices = [dataclasses.replace(s, pose_std_m=0.008) for s in make_slices(rods)]
    blurred = geometric_completion(blurred_slices, CFG, np.random.default_rng(0))
    (a,), (b,) = sharp.pipes, blurred.pipes
    assert a.pose_std_m == 0.0 and b.pose_std_m == pytest.approx(0.008)
    assert b.confidence == pytest.approx(a.confidence * pose_confidence(0.008))
    assert b.confidence < 0.6 * a.confidence
    path = tmp_path / "pipes.json"
    write_pipes_json(path, Reconstruction(blurred.pipes, blurred.dense, blurred.labels), {})
    assert json.loads(path.read_text())["pipes"][0]["pose_std_m"] == pytest.approx(0.008)
    assert read_pipes_json(path)[0].pose_std_m == pytest.approx(0.008)
