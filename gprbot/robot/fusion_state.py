"""The fusion task's state: a queue of sensor messages into PoseFuser, and what the robot reads back.

Producers (IMU, encoders) `submit` messages; the fusion task pushes them into the filter in arrival
order (the filter re-orders within its window). The control loop reads `yaw_rad` and `gyro_z_rad_s`;
the survey tags traces with `poses_between`.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable

from gprbot.config import Config
from gprbot.fusion.fuser import PoseFuser, SensorMessage
from gprbot.fusion.snapshot import take_snapshot
from gprbot.messages import FusionSnapshot, ImuSample, Pose

MAX_BATCH = 20  # messages pushed into the filter before the task lets the rest of the loop run


class FusionState:
    """PoseFuser behind an asyncio queue, with the latest heading and gyro rate for heading hold."""

    def __init__(self, cfg: Config, initial_pose: tuple[float, float, float]) -> None:
        x, y, yaw = initial_pose
        self.fuser = PoseFuser(cfg.fusion, cfg.motors, initial_position=(x, y, 0.0), initial_yaw_rad=yaw)
        self.initial_yaw_rad = yaw
        self.gyro_z_rad_s = 0.0
        self.messages = 0
        self.cpu_s = 0.0  # the filter's own CPU time (its pushes), for the benchmark and `status`
        self._pending: deque[SensorMessage] = deque()
        self._arrived = asyncio.Event()

    def submit(self, message: SensorMessage) -> None:
        """Queue one sensor message for the filter (never blocks)."""
        if isinstance(message, ImuSample) and message.gyro is not None:
            self.gyro_z_rad_s = float(message.gyro[2])
        self._pending.append(message)
        self._arrived.set()

    def snapshot(self, t: float) -> FusionSnapshot:
        """The filter's state and the messages still waiting for it (a run log's first record, for replay)."""
        return take_snapshot(t, self.fuser, self._pending)

    @property
    def ready(self) -> bool:
        """Whether the filter has initialised (after its at-rest period) and emits poses."""
        return self.fuser.ekf.initialized and len(self.fuser.history) >= 2

    @property
    def yaw_rad(self) -> float:
        """The fused heading (rad); the start heading until the filter is ready."""
        return self.fuser.yaw_rad if self.fuser.ekf.initialized else self.initial_yaw_rad

    @property
    def gyro_bias_z(self) -> float:
        """The filter's gyro-z bias estimate (rad/s), to debias the raw rate used for damping."""
        return float(self.fuser.ekf.gyro_bias[2]) if self.fuser.ekf.initialized else 0.0

    def newest_pose(self) -> Pose | None:
        """The most recent output pose."""
        return self.fuser.history.newest()

    def poses_between(self, t0: float, t1: float, margin_s: float = 0.05) -> list[Pose]:
        """Output poses from just before t0 to just after t1."""
        return self.fuser.history.between(t0 - margin_s, t1 + margin_s)

    async def run(self, beat: Callable[[], None]) -> None:
        """The fusion task: push submitted messages into the filter, in submission order, as they come."""
        while True:
            beat()
            if not self._pending:
                self._arrived.clear()
                try:
                    async with asyncio.timeout(0.5):  # not wait_for: on 3.11 it can swallow a cancel
                        await self._arrived.wait()
                except TimeoutError:
                    continue
            began = time.thread_time()
            pushed = 0
            while self._pending:
                if pushed and pushed % MAX_BATCH == 0:
                    # A backlog (after a stall, under CPU load) is drained in slices: one long drain held
                    # the loop for over a second, so the encoders' serial replies timed out and the
                    # wheels were stopped mid-line, which made survey results depend on the machine's load.
                    self.cpu_s += time.thread_time() - began
                    beat()
                    await asyncio.sleep(0)
                    began = time.thread_time()
                self.fuser.push(self._pending.popleft())
                self.messages += 1
                pushed += 1
            self.cpu_s += time.thread_time() - began
            await asyncio.sleep(0)  # let the producers run between batches
