"""Plan tracking: the planned velocity plus a proportional pull towards where the antenna should be.

Open-loop velocities leave the motors' lag and the wheels' radius errors in the survey's geometry
(lines a centimetre off their spacing, short lines). The fused pose trails the sensors by the filter's
reorder window, so it is compared with where the plan was at the pose's own time. Pure.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gprbot.geometry import antenna_xy
from gprbot.messages import Pose
from gprbot.motion.planner import Segment

MAX_POSE_AGE_S = 0.5  # an older pose (filter stalled) gives no correction: plain planned velocity


def tracking_velocity(segment: Segment, elapsed_s: float, now: float, pose: Pose | None,
                      lever_arm: tuple[float, float, float], gain_per_s: float = 1.0,
                      max_correction_m_s: float = 0.05) -> NDArray[np.float64]:
    """Site-frame velocity for `elapsed_s` into `segment`: planned, plus gain × position error (clamped)."""
    velocity = np.asarray(segment.velocity, dtype=np.float64)
    if pose is None or not 0.0 <= now - pose.t <= MAX_POSE_AGE_S:
        return velocity
    duration = max(segment.t_end - segment.t_start, 1e-9)
    fraction = min(max((elapsed_s - (now - pose.t)) / duration, 0.0), 1.0)
    planned = segment.start_xy + fraction * (segment.end_xy - segment.start_xy)
    correction = gain_per_s * (planned - antenna_xy(pose, lever_arm))
    size = float(np.hypot(correction[0], correction[1]))
    if size > max_correction_m_s:
        correction *= max_correction_m_s / size
    return np.asarray(velocity + correction)
