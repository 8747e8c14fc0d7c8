"""Simulated trajectory: the antenna follows the plan closely; the estimate errs as configured."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from gprbot.config import PoseNoiseConfig, SurveyConfig
from gprbot.motion.planner import plan_survey
from gprbot.sim.trajectory import simulate_trajectory


def test_true_antenna_tracks_plan_and_estimate_errs_by_configured_amount() -> None:
    plan = plan_survey(SurveyConfig(lines=4, length_m=1.0))
    noise = PoseNoiseConfig(position_std_m=0.003, yaw_std_deg=0.2, drift_m_per_m=0.002, seed=3)
    traj = simulate_trajectory(plan, (0.25, 0.0, 0.0), noise)
    t = traj.times
    wander = np.linalg.norm(traj.true_antenna_xy(t) - plan.position(t), axis=1)
    assert 0.001 < np.sqrt(np.mean(wander**2)) < 0.01  # a few mm off the plan, not zero, not cm

    true_pos = np.stack([p.position for p in traj.true_poses])
    est_pos = np.stack([p.position for p in traj.estimated_poses])
    err = np.linalg.norm(est_pos - true_pos, axis=1)
    assert 0.0005 < np.sqrt(np.mean(err**2)) < 0.01
    yaw = Rotation.from_quat(np.stack([p.orientation for p in traj.true_poses])).as_euler("xyz", degrees=True)[:, 2]
    assert np.abs(yaw).max() < 1.0  # the robot never rotates: yaw only wobbles under heading hold


def test_the_base_carries_the_antenna_on_the_lever_arm() -> None:
    plan = plan_survey(SurveyConfig(lines=1, length_m=0.5))
    traj = simulate_trajectory(plan, (0.25, 0.0, 0.0), PoseNoiseConfig(seed=0))
    base = np.stack([p.position for p in traj.true_poses])[:, :2]
    ant = traj.true_antenna_xy(traj.times)
    assert np.allclose(ant[:, 0] - base[:, 0], 0.25, atol=1e-3)


def test_seeded_and_reproducible() -> None:
    plan = plan_survey(SurveyConfig(lines=2, length_m=0.5))
    a = simulate_trajectory(plan, (0.25, 0.0, 0.0), PoseNoiseConfig(seed=5))
    b = simulate_trajectory(plan, (0.25, 0.0, 0.0), PoseNoiseConfig(seed=5))
    assert np.array_equal(a.estimated_poses[-1].position, b.estimated_poses[-1].position)
