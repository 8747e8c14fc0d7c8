"""Simulated robot trajectory: the true path around a plan, and a pose estimate with realistic errors.

Until the fusion stack drives the simulation, the robot is modelled by what matters to the survey:
its antenna wanders a few millimetres off the planned line (tracking error), its yaw wobbles under
heading hold, and the pose estimate drifts with distance travelled and carries white noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from gprbot.config import PoseNoiseConfig
from gprbot.geometry import antenna_positions
from gprbot.messages import Pose
from gprbot.motion.planner import SurveyPlan

POSE_RATE_HZ = 100.0
TRACKING_STD_M = 0.004  # lateral wander of a kiwi base under closed-loop line following
TRUE_YAW_STD_DEG = 0.15  # residual yaw wobble under heading hold


@dataclass(frozen=True)
class SimulatedTrajectory:
    """True and estimated base poses on a common time grid, plus the lever arm used."""

    times: NDArray[np.float64]
    true_poses: tuple[Pose, ...]
    estimated_poses: tuple[Pose, ...]
    lever_arm: NDArray[np.float64]

    def true_antenna_xy(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """True antenna midpoint (n, 2) at times t (for the forward model)."""
        arm = (float(self.lever_arm[0]), float(self.lever_arm[1]), float(self.lever_arm[2]))
        ant = antenna_positions(self.true_poses, arm)
        return np.stack([np.interp(t, self.times, ant[:, k]) for k in range(2)], axis=1)


def _smooth_noise(rng: np.random.Generator, n: int, std: float, sigma_samples: float) -> NDArray[np.float64]:
    # Filter a longer sequence and keep its middle: at the edges a Gaussian filter averages fewer
    # independent samples, which would give the ends several times the intended spread.
    pad = int(4 * sigma_samples) + 1
    raw = gaussian_filter1d(rng.standard_normal(n + 2 * pad), sigma_samples)[pad : pad + n]
    scale = raw.std()
    return np.asarray(raw / scale * std) if scale > 0 else np.zeros(n)


def simulate_trajectory(
    plan: SurveyPlan, lever_arm: tuple[float, float, float], noise: PoseNoiseConfig
) -> SimulatedTrajectory:
    """Simulate the true base path around `plan` (an antenna plan) and a drifting pose estimate."""
    rng = np.random.default_rng(noise.seed)
    times = np.arange(0.0, plan.duration_s + 1e-9, 1.0 / POSE_RATE_HZ)
    n = times.size
    arm = np.asarray(lever_arm, dtype=np.float64)
    vel = plan.velocity(times)
    speed = np.linalg.norm(vel, axis=1)
    heading = np.where(speed[:, None] > 0, vel / np.maximum(speed, 1e-12)[:, None], 0.0)
    lateral = np.stack([-heading[:, 1], heading[:, 0]], axis=1)
    # The true antenna wanders sideways of its direction of travel; it does not wander while parked.
    wander = _smooth_noise(rng, n, TRACKING_STD_M, 0.5 * POSE_RATE_HZ)
    true_ant = np.column_stack([plan.position(times) + lateral * wander[:, None], np.zeros(n)])
    true_yaw = np.deg2rad(_smooth_noise(rng, n, TRUE_YAW_STD_DEG, 1.0 * POSE_RATE_HZ))
    true_rot = Rotation.from_euler("z", true_yaw[:, None])
    true_base = true_ant - true_rot.apply(arm)
    true_base[:, 2] = 0.0

    # Estimate: drift grows with distance travelled (a random walk per metre), plus white noise.
    step = np.linalg.norm(np.diff(true_base[:, :2], axis=0, prepend=true_base[:1, :2]), axis=1)
    walk = np.cumsum(rng.standard_normal((n, 2)) * np.sqrt(step)[:, None], axis=0) * noise.drift_m_per_m
    white = rng.standard_normal((n, 2)) * noise.position_std_m
    est_base = true_base.copy()
    est_base[:, :2] += walk + gaussian_filter1d(white, 2.0, axis=0, mode="nearest")
    est_yaw = true_yaw + np.deg2rad(_smooth_noise(rng, n, noise.yaw_std_deg, 0.5 * POSE_RATE_HZ))
    est_rot = Rotation.from_euler("z", est_yaw[:, None])

    true_q = true_rot.as_quat()
    est_q = est_rot.as_quat()
    true_poses = tuple(Pose(float(t), true_base[i], true_q[i]) for i, t in enumerate(times))
    est_poses = tuple(Pose(float(t), est_base[i], est_q[i]) for i, t in enumerate(times))
    return SimulatedTrajectory(times, true_poses, est_poses, arm)
