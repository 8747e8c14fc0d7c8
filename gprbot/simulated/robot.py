"""The simulated robot: device emulators fed by a simulated world, so the daemon runs its real drivers.

- Motors: a RoboClawEmulator on a pty, answering from its own thread (as a controller on USB answers
  whatever the host's loop is doing); the MotorDriver talks RoboClaw packet serial to it.
- GPR: a GprSdkEmulator on loopback whose traces come from the forward model at the robot's TRUE
  antenna position at the instant each trace is triggered.
- RealSense D435i: a software device (drivers/realsense/emulator) that the RealsenseDriver opens as it
  would a camera on USB, fed with BMI055-like gyro (400 Hz) and accelerometer (250 Hz) samples of the
  true motion and with RGB-D frames of the floor (sim/camera) rendered at the true pose, texture-poor
  patch included.
- Truth: the base's planar pose is integrated from the emulated motors' shaft speeds through the kiwi
  forward kinematics, with each wheel's true radius a little off nominal — so the wheels alone would
  drift in yaw and heading hold has real work to do, seen by the gyro but not by the encoders — and
  with each wheel slipping (a slowly wandering fraction and rare slip events, sim/encoders' model).
"""

from __future__ import annotations

import asyncio
import bisect
import dataclasses
import math
import threading
import time
from collections import deque
from collections.abc import AsyncIterator, Callable

import numpy as np
from numpy.typing import NDArray

from gprbot.config import Config
from gprbot.drivers.gpr.emulator import GprSdkEmulator
from gprbot.drivers.motors.emulator import RoboClawEmulator
from gprbot.drivers.realsense.emulator import D435iEmulator
from gprbot.geometry import CameraMount, planar_antenna_xy
from gprbot.messages import ImuSample
from gprbot.motion.kinematics import KiwiKinematics, integrate_body_twist
from gprbot.sim.camera import CameraModel, FloorCamera
from gprbot.sim.encoders import EncoderModel
from gprbot.sim.forward import simulate_bscan
from gprbot.sim.imu import ImuModel
from gprbot.sim.scene import Scene, load_scene
from gprbot.survey import start_pose

GRAVITY_M_S2 = 9.80665
WHEEL_RADIUS_ERROR = (0.012, -0.009, 0.004)  # true radius / nominal - 1 for wheels 0, 1, 2
MIN_STEP_S = 1e-4  # the truth's shortest integration step


class SimRobot:
    """The emulated devices and the true state of the simulated robot on its slab."""

    def __init__(self, cfg: Config, scene: Scene | None = None, clock: Callable[[], float] = time.monotonic,
                 imu_model: ImuModel | None = None) -> None:
        self.cfg = cfg
        self.scene = scene or load_scene(cfg.sim.scene)
        self.clock = clock
        self.imu_model = imu_model or ImuModel()
        self.kinematics = KiwiKinematics.from_config(cfg.motors)
        self.radius_scale = 1.0 + np.array(WHEEL_RADIUS_ERROR)
        self._rng = np.random.default_rng(cfg.sim.seed)
        self._gyro_bias = self._rng.normal(0.0, self.imu_model.gyro_turn_on_bias_std, 3)
        self._accel_bias = self._rng.normal(0.0, self.imu_model.accel_turn_on_bias_std, 3)
        addresses = sorted({address for address, _ in cfg.motors.wheel_map})
        self.motors = RoboClawEmulator(addresses, cfg.motors.encoder_counts_per_rev, clock, seed=cfg.sim.seed)
        self.gpr = GprSdkEmulator(self._trace, device_clock=clock, enforce_device_ranges=False)
        self.pose = np.array(start_pose(cfg), dtype=np.float64)  # true (x, y, yaw) of the base
        self.velocity = np.zeros(2)  # true site-frame velocity (m/s)
        self.omega = 0.0
        self.motors.record_motion(1.0 / self.imu_model.gyro_rate_hz)  # the truth's (and the IMU's) time grid
        self._t = clock()
        self._angles = self.wheel_angles()
        # (end time, ω, yaw, site-frame acceleration) of each truth step, for the IMU samples inside it
        self._steps: deque[tuple[float, float, float, NDArray[np.float64]]] = deque(maxlen=8000)
        self._step_dt = 1.0 / self.imu_model.gyro_rate_hz
        self.traces_served = 0
        self.imu_emitted = 0  # IMU samples pushed into the emulated D435i
        self.loop_cpu_s = 0.0  # CPU the simulator spends on the event loop (IMU synthesis, GPR forward model)
        self._slip_rng = np.random.default_rng(cfg.sim.seed + 7919)
        self.slip = np.zeros(3)  # how much faster than the ground under it each wheel turns (fraction)
        self._slip_wander = np.zeros(3)
        self._slip_events: list[tuple[float, int]] = []  # (end time, wheel)
        self._history: deque[tuple[float, float, float, float]] = deque(maxlen=8000)  # (t, x, y, yaw): 20 s
        self._history_lock = threading.Lock()
        rs = cfg.realsense
        mount = CameraMount(cfg.mount.camera_position_m, cfg.mount.camera_pitch_down_deg)
        self.floor_camera = FloorCamera(model=CameraModel(rs.width, rs.height, float(rs.fps), mount=mount),
                                        seed=cfg.sim.seed)
        k = self.floor_camera.intrinsics
        self.camera = D435iEmulator(rs, (k.fx, k.fy, k.cx, k.cy), clock, self.render_frame)

    async def start(self) -> Config:
        """Serve the emulators; the config with motors.port and gpr_device pointed at them."""
        port = self.motors.serve_pty(threaded=True)  # a controller answers whatever the host's loop is doing
        await self.gpr.start()
        self._t, self._angles = self.clock(), self.wheel_angles()
        self._remember(self._t)
        self.camera.start()
        motors = dataclasses.replace(self.cfg.motors, port=port, controller_ports=())
        return dataclasses.replace(self.cfg, motors=motors, gpr_device=self.gpr.driver_config(self.cfg.gpr_device))

    async def close(self) -> None:
        """Stop the emulators."""
        self.camera.stop()
        await self.gpr.stop()
        self.motors.close()

    # ----- the true state -----------------------------------------------------------------------
    def wheel_speeds(self) -> NDArray[np.float64]:
        """The emulated motors' shaft speeds now (rad/s), in wheel_map order."""
        return np.array([self.motors.motor_speed(a, c) for a, c in self.cfg.motors.wheel_map])

    def wheel_angles(self) -> NDArray[np.float64]:
        """The emulated motors' shaft angles now (rad), in wheel_map order (exact: closed-form motor model)."""
        counts = np.array(self.motors.encoder_positions(self.cfg.motors.wheel_map))
        return counts * (2 * math.pi / self.cfg.motors.encoder_counts_per_rev)

    def advance(self) -> float:
        """Integrate the true pose up to now from the wheels' turns; the time reached.

        In the emulator's 2.5 ms steps of how the motors actually turned, so the truth (and the IMU
        made from it) is the same however late this runs — a stalled loop catches up on the same path.
        The turn of each wheel over a step over its true radius gives the body's displacement; an
        encoder reset (a jump no motor can make) falls back to speed × dt.
        """
        scale = 2 * math.pi / self.cfg.motors.encoder_counts_per_rev
        for t, counts in self.motors.motion_since(self._t, self.cfg.motors.wheel_map):
            self._step(t, np.asarray(counts) * scale)
        return self._t

    def _step(self, t: float, angles: NDArray[np.float64]) -> None:
        dt = t - self._t
        if dt < MIN_STEP_S:  # left to the next step: speeds from a sliver of a step are rounding noise
            return
        turned = angles - self._angles
        limit = 2.0 * self.cfg.motors.max_wheel_speed_rad_s * dt + 1e-3
        if np.any(np.abs(turned) > limit):
            turned = self.wheel_speeds() * dt
        self._update_slip(t, dt, turned)
        twist = self.kinematics.body_twist(turned * self.radius_scale / (1.0 + self.slip) / dt)
        previous, last_velocity = self.pose[:2].copy(), self.velocity
        self.pose = integrate_body_twist(self.pose, twist, dt)
        self.velocity = (self.pose[:2] - previous) / dt
        self.omega = float(twist[2])
        accel = (self.velocity - last_velocity) / (0.5 * (dt + self._step_dt))  # between the steps' mean speeds
        self._steps.append((t, self.omega, float(self.pose[2]), accel))
        self._t, self._angles, self._step_dt = t, angles, dt
        self._remember(t)

    def _update_slip(self, now: float, dt: float, turned: NDArray[np.float64]) -> None:
        """Each wheel's slip: a wandering fraction (Ornstein–Uhlenbeck) plus rare events; none when parked."""
        m = EncoderModel()
        alpha = math.exp(-dt / m.slip_correlation_s)
        rng = self._slip_rng
        self._slip_wander = alpha * self._slip_wander + rng.normal(0.0, m.slip_std * math.sqrt(1 - alpha**2), 3)
        if rng.random() < m.slip_event_rate_hz * dt:
            self._slip_events.append((now + m.slip_event_duration_s, int(rng.integers(3))))
        self._slip_events = [(end, wheel) for end, wheel in self._slip_events if end > now]
        events = np.zeros(3)
        for _, wheel in self._slip_events:
            events[wheel] += m.slip_event_fraction
        moving = np.abs(turned) > 1e-6
        self.slip = (self._slip_wander + events) * moving

    def _remember(self, t: float) -> None:
        with self._history_lock:
            self._history.append((t, float(self.pose[0]), float(self.pose[1]), float(self.pose[2])))

    def true_pose_at(self, times: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """The true (x, y, yaw) at each time (interpolated), or None if a time is past the newest known."""
        with self._history_lock:
            history = list(self._history)
        if not history or times.max() > history[-1][0]:
            return None
        stamps = [h[0] for h in history]
        out = np.empty((times.size, 3))
        for i, t in enumerate(times):
            j = min(max(bisect.bisect_right(stamps, t), 1), len(history) - 1)
            (t0, *a), (t1, *b) = history[j - 1], history[j]
            w = 0.0 if t1 <= t0 else min(max((t - t0) / (t1 - t0), 0.0), 1.0)
            out[i] = (1 - w) * np.array(a) + w * np.array(b)
        return out

    def render_frame(self, t: float) -> tuple[NDArray[np.uint8], NDArray[np.uint16]] | None:
        """The camera's colour and depth (mm) exposed around t, or None until the truth covers the exposure."""
        half = 0.5 * self.floor_camera.model.exposure_s
        poses = self.true_pose_at(np.array([t - half, t, t + half]))
        if poses is None:
            return None
        rt = [(_yaw_matrix(yaw), np.array([x, y, 0.0])) for x, y, yaw in poses]
        frame = self.floor_camera.render_moving(t, rt[0], rt[1], rt[2])
        depth = np.rint(frame.depth_m * np.float32(1000.0)).astype(np.uint16)  # the D435i's 1 mm depth unit
        return frame.color, depth

    def antenna_xy(self) -> NDArray[np.float64]:
        """The true antenna midpoint (x, y) in the site frame now."""
        self.advance()
        return planar_antenna_xy(float(self.pose[0]), float(self.pose[1]), float(self.pose[2]),
                                 self.cfg.mount.antenna_lever_arm_m)

    def _trace(self, number: int) -> NDArray[np.float32]:
        """Trace `number` as the antenna records it at its true position now (the emulator's source)."""
        del number
        began = time.thread_time()
        mid = self.antenna_xy()[None, :]
        yaw = float(self.pose[2])
        self.traces_served += 1
        bscan = simulate_bscan(self.scene, mid, self.cfg.gpr, self._rng, offset_dir=(math.cos(yaw), math.sin(yaw)))
        self.loop_cpu_s += time.thread_time() - began
        return np.asarray(bscan[0], dtype=np.float32)

    # ----- the IMU ------------------------------------------------------------------------------
    async def feed_imu(self, period_s: float = 0.01) -> AsyncIterator[int]:
        """Push the IMU samples into the emulated D435i every period_s; yields the number pushed each time."""
        to_camera = self.floor_camera.model.mount.rotation().T  # the D435i reports in its optical axes
        async for batch in self.imu_batches(period_s):
            began = time.thread_time()
            for sample in batch:
                gyro = None if sample.gyro is None else to_camera @ sample.gyro
                accel = None if sample.accel is None else to_camera @ sample.accel
                self.camera.push_imu(sample.t, gyro, accel)
            self.imu_emitted += len(batch)
            self.loop_cpu_s += time.thread_time() - began
            yield len(batch)

    async def imu_batches(self, period_s: float = 0.01) -> AsyncIterator[list[ImuSample]]:
        """Every period_s, the gyro and accelerometer samples due since the last batch (in time order)."""
        model = self.imu_model
        gyro_dt, accel_dt = 1.0 / model.gyro_rate_hz, 1.0 / model.accel_rate_hz
        start = self.advance()
        self._steps.clear()
        next_gyro, next_accel = start, start
        while True:
            await asyncio.sleep(period_s)
            began = time.thread_time()
            self.advance()
            batch: list[ImuSample] = []
            while self._steps:  # each sample from the truth step it falls in, not from the truth now
                end, omega, yaw, accel_world = self._steps.popleft()
                while next_gyro <= end:
                    batch.append(ImuSample(next_gyro, gyro=self._gyro_sample(omega)))
                    next_gyro += gyro_dt
                while next_accel <= end:
                    batch.append(ImuSample(next_accel, accel=self._accel_sample(accel_world, yaw)))
                    next_accel += accel_dt
            batch.sort(key=lambda m: m.t)
            self.loop_cpu_s += time.thread_time() - began
            yield batch

    def _gyro_sample(self, omega: float) -> NDArray[np.float64]:
        m = self.imu_model
        true = np.array([0.0, 0.0, omega])
        noisy = true + self._gyro_bias + self._rng.normal(0.0, m.gyro_noise_density * math.sqrt(m.gyro_rate_hz), 3)
        return np.asarray(np.round(noisy / m.gyro_lsb) * m.gyro_lsb)

    def _accel_sample(self, accel_world: NDArray[np.float64], yaw: float) -> NDArray[np.float64]:
        m = self.imu_model
        c, s = math.cos(yaw), math.sin(yaw)
        body = np.array([c * accel_world[0] + s * accel_world[1], -s * accel_world[0] + c * accel_world[1],
                         GRAVITY_M_S2])  # specific force on a level slab: gravity's reaction is +z
        noisy = body + self._accel_bias + self._rng.normal(
            0.0, m.accel_noise_density * math.sqrt(m.accel_rate_hz), 3)
        return np.asarray(np.round(noisy / m.accel_lsb) * m.accel_lsb)


def _yaw_matrix(yaw: float) -> NDArray[np.float64]:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
