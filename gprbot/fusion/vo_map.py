"""Map keyframes: floor the camera saw before, found again, so the heading stops drifting line by line.

Chained keyframe-to-keyframe VO is a random walk in yaw: about 0.01° per keyframe on the simulated
floor, about 0.2° over a 10-line survey, the same size as the issue's whole budget. A survey drives
parallel lines 0.1 m apart while the camera sees a strip of floor ~0.45 m wide, so each line passes over
floor that the previous one saw. The map keeps a few keyframes (image, corners with depth, and where VO
itself put them) spaced along the path. When the robot is back within reach of one that is old enough
(not the chain it is on), the frame is tracked against it, its image first warped by the floor's
homography for the predicted motion (`vo_geometry.warped_toward`), and the motion from it becomes a
measurement that the filter
applies against that keyframe's stored pose (a stochastic clone of its own: correlations are kept).
Only VO's own chained pose is used for the choice and the prediction, so the stage stays pure.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from gprbot.fusion.so3 import FloatArray
from gprbot.fusion.vo_geometry import Keyframe


@dataclass(frozen=True)
class MapConfig:
    """How many map keyframes, how far apart, and when one is looked for again."""

    slots: int = 20  # the filter carries one 6-DOF clone per slot (FusionConfig.vo_map_slots)
    spacing_m: float = 0.07  # a new keyframe joins the map when none lies this close (less than line spacing)
    travel_m: float = 0.2  # ... and the path has gone this far since the last one joined
    reach_m: float = 0.15  # a map keyframe is tried again from this close (horizontal, base_link)
    min_age_s: float = 8.0  # younger ones are on the chain VO is following anyway
    period_s: float = 0.25  # one attempt per this long (each costs one more tracking step)
    min_inliers: int = 60  # fewer (little overlap, corners at one edge) gave yaw errors of 2-3 claimed σ
    max_surprise_m: float = 0.05  # a found keyframe this far from where VO's chain expects it is a wrong lock
    max_surprise_rad: float = 0.02


@dataclass
class MapKeyframe:
    """One stored keyframe and the pose VO had for it (base_link in VO's own chained frame)."""

    slot: int
    keyframe: Keyframe
    position: FloatArray
    rotation: FloatArray


class KeyframeMap:
    """A few keyframes spaced along the path; which to store, which to look for again."""

    def __init__(self, config: MapConfig) -> None:
        self.config = config
        self.entries: dict[int, MapKeyframe] = {}
        self._path_since_stored = 0.0
        self._last_position: FloatArray | None = None
        self._last_attempt = -math.inf
        self.attempts = 0
        self.found = 0

    def moved_to(self, position: FloatArray) -> None:
        """The base's (VO) position at a new frame: counts the path since the last map keyframe."""
        if self._last_position is not None:
            self._path_since_stored += float(np.linalg.norm(position[:2] - self._last_position[:2]))
        self._last_position = np.asarray(position, dtype=np.float64).copy()

    def offer(self, keyframe: Keyframe, position: FloatArray, rotation: FloatArray) -> int:
        """Store a new keyframe if the map lacks one near it; its slot, or −1 when not stored."""
        c = self.config
        if c.slots <= 0:
            return -1
        if self.entries and self._path_since_stored < c.travel_m:
            return -1
        if any(self._distance(e, position) < c.spacing_m for e in self.entries.values()):
            return -1
        free = [s for s in range(c.slots) if s not in self.entries]
        # full: give up the one farthest from here (the path is least likely to come back to it soon)
        slot = free[0] if free else max(self.entries.values(), key=lambda e: self._distance(e, position)).slot
        copy = dataclasses.replace(keyframe, tracked=keyframe.points_2d.copy())
        self.entries[slot] = MapKeyframe(slot, copy, np.asarray(position, dtype=np.float64).copy(),
                                         np.asarray(rotation, dtype=np.float64).copy())
        self._path_since_stored = 0.0
        return slot

    def candidate(self, t: float, position: FloatArray) -> MapKeyframe | None:
        """The nearest map keyframe within reach and old enough, if an attempt is due now."""
        c = self.config
        if t - self._last_attempt < c.period_s:
            return None
        near = [e for e in self.entries.values()
                if t - e.keyframe.t >= c.min_age_s and self._distance(e, position) <= c.reach_m]
        if not near:
            return None
        self._last_attempt = t
        self.attempts += 1
        return min(near, key=lambda e: self._distance(e, position))

    @staticmethod
    def _distance(entry: MapKeyframe, position: FloatArray) -> float:
        return float(np.linalg.norm(entry.position[:2] - np.asarray(position)[:2]))
