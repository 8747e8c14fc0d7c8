"""The robot the daemon runs: devices, fusion, the 50 Hz motion loop, survey, recorder, worker, shell.

`start_devices()` brings the hardware up (or the simulated robot's emulators, with the same drivers);
`task_table()` is the daemon's declared table of tasks over them; `estop()`/`shutdown()` are the
paths that stop the wheels first.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Awaitable, Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from gprbot.config import CONTROL_PERIOD_S, SIMULATED, Config
from gprbot.drivers.contract import Driver
from gprbot.drivers.gpr.driver import GprDriver
from gprbot.drivers.motors.driver import MotorDriver
from gprbot.drivers.realsense.driver import RealsenseDriver
from gprbot.errors import ConfigError, DriverError
from gprbot.geometry import CameraMount
from gprbot.infer.worker import InferenceWorker
from gprbot.messages import ImuSample, VoMeasurement, WheelSpeeds
from gprbot.motion.heading import HeadingHoldDrive, HeadingHoldGains
from gprbot.motion.jog import JogController
from gprbot.robot.fusion_state import FusionState
from gprbot.robot.recorder import Recorder
from gprbot.robot.survey_runner import SurveyRunner
from gprbot.robot.vo_task import VoTask
from gprbot.shell.handler import EventBus
from gprbot.shell.server import SerialShell, ShellServer
from gprbot.supervisor import Supervisor, TaskSpec
from gprbot.survey import start_pose

if TYPE_CHECKING:
    from gprbot.simulated.robot import SimRobot

log = logging.getLogger(__name__)
ESTOP_REPEAT_S = 0.5  # while latched, a repeated e-stop re-sends the stop at most this often


class ConsoleInfo(Protocol):
    """What `status` shows of a front end the daemon runs over this runtime (the web console)."""

    @property
    def url(self) -> str: ...

    @property
    def browser_count(self) -> int: ...


class RobotRuntime:
    """Everything the daemon supervises, and the operations the shell handler calls."""

    def __init__(self, cfg: Config, *, shell_host: str = "127.0.0.1", shell_port: int | None = None,
                 token_file: str | None = None, clock: Callable[[], float] = time.monotonic,
                 use_worker: bool = True) -> None:
        self.cfg = cfg
        self.clock = clock
        self.sim: SimRobot | None = None
        if cfg.simulated:
            if not cfg.all_simulated:
                raise ConfigError(f"mixing simulated and real devices is not supported: set motors.port, "
                                  f"gpr_device.host and realsense.source all to '{SIMULATED}', or none of them")
            # Imported only here: on the robot the runtime never loads the simulated world.
            from gprbot.simulated.robot import SimRobot

            self.sim = SimRobot(cfg, clock=clock)
        self.fusion = FusionState(cfg, start_pose(cfg))
        gains = HeadingHoldGains(cfg.motion.heading_kp_per_s, cfg.motion.heading_ki_per_s2,
                                 cfg.motion.heading_kd_gyro, cfg.motion.max_heading_omega_rad_s)
        self.drive = HeadingHoldDrive.from_config(cfg.motors, gains)
        self.drive.reset(start_pose(cfg)[2])
        self.jog = JogController(cfg.motion.jog_max_speed_m_s, cfg.motion.jog_deadman_timeout_s,
                                 cfg.motion.jog_max_duration_s)
        self.events = EventBus()
        self.recorder = Recorder()
        self.worker = InferenceWorker(cfg) if use_worker else None
        truth = [p.points for p in self.sim.scene.pipes] if self.sim is not None else []
        self.survey = SurveyRunner(cfg, self.fusion, self.recorder, self.emit, worker=self.worker, clock=clock,
                                   run_meta=self._run_meta, truth_axes=truth, links_fault=self._links_fault,
                                   may_resume=lambda: not (self.estopped or self.stopping))
        self.shell_host = shell_host
        self.shell_port = cfg.shell.port if shell_port is None else shell_port
        self.token_file = token_file
        self.shell: ShellServer | None = None
        self.web: ConsoleInfo | None = None  # set by the web console task while it listens
        self.web_error: str | None = None  # why the web console is not listening, if it is not
        self.motors: MotorDriver | None = None
        self.gpr: GprDriver | None = None
        self.realsense: RealsenseDriver | None = None
        self.camera_frames = 0  # RGB-D frames received from the RealSense driver
        mount = CameraMount(cfg.mount.camera_position_m, cfg.mount.camera_pitch_down_deg)
        self.vo = VoTask(mount, self._on_vo, map_slots=cfg.fusion.vo_map_slots, clock=clock)
        self.supervisor: Supervisor | None = None
        self.estopped = False
        self._estop_stop: asyncio.Future[None] | None = None
        self._estop_confirmed_t = -math.inf
        self.stopping = False
        self.moving = False
        self.last_command: np.ndarray = np.zeros(3)

    # ----- lifecycle ----------------------------------------------------------------------------
    async def start_devices(self) -> None:
        """Start the emulators (sim), the motor and GPR drivers and the inference worker, then bind the shell.

        A shell config that leaves the robot unreachable (no token beyond loopback, a token file others
        can read, a port in use) is a ConfigError here, before READY=1, so systemd sees the start fail
        instead of a healthy-looking robot that nobody can reach."""
        cfg = self.cfg
        if self.sim is not None:
            cfg = await self.sim.start()
        Path(cfg.runs_dir).mkdir(parents=True, exist_ok=True)
        self.motors = MotorDriver(cfg.motors, self.clock, ports=dict(cfg.motors.controller_ports))
        await self.motors.start()
        self.gpr = GprDriver(cfg.gpr_device, self.clock)
        await self.gpr.start()
        imu_to_base = CameraMount(cfg.mount.camera_position_m, cfg.mount.camera_pitch_down_deg).rotation()
        if self.sim is not None:  # the emulated D435i, opened through the same source as a camera on USB
            self.realsense = RealsenseDriver(cfg.realsense, self.clock, source_factory=self.sim.camera.source_factory,
                                             imu_to_base=imu_to_base)
        else:
            self.realsense = RealsenseDriver(cfg.realsense, self.clock, imu_to_base=imu_to_base)
        await self.realsense.start()
        self.vo.start(asyncio.get_running_loop())
        if self.worker is not None:
            await self.worker.start()
        await self.start_shell()

    async def close_devices(self) -> None:
        """Stop the drivers, the worker and the emulators (best effort, each independently)."""
        steps: list[tuple[str, Callable[[], Awaitable[None]] | None]] = [
            ("motors", self.motors.close if self.motors is not None else None),
            ("gpr", self.gpr.close if self.gpr is not None else None),
            ("realsense", self.realsense.close if self.realsense is not None else None),
            ("vo", self._stop_vo),
            ("worker", self.worker.close if self.worker is not None else None),
            ("sim", self.sim.close if self.sim is not None else None),
        ]
        if self.shell is not None:
            with contextlib.suppress(TimeoutError):  # a client that stopped reading must not hold us up
                async with asyncio.timeout(3.0):
                    await self.shell.close()
        for name, close in steps:
            if close is None:
                continue
            began = self.clock()
            try:
                async with asyncio.timeout(5.0):
                    await close()
            except (DriverError, TimeoutError) as exc:
                log.error("closing %s failed: %r", name, exc)
            log.debug("closed %s in %.3f s", name, self.clock() - began)

    async def shutdown(self) -> None:
        """SIGTERM: wheels to zero first, end the current line and close the run log."""
        self.stopping = True
        await self.stop_wheels()
        await self.survey.shutdown()
        self.emit("daemon stopping")

    def task_table(self, frontends: Sequence[TaskSpec] = ()) -> list[TaskSpec]:
        """The daemon's declared tasks: name, coroutine, watchdog deadline, restart policy; `frontends`
        (the web console, built by the daemon) run after the TCP shell."""
        tasks = [
            TaskSpec("fusion", self.fusion.run, watchdog_s=2.0, restart="always"),
            TaskSpec("motors.encoders", self._run_encoders, watchdog_s=1.0, restart="always"),
            TaskSpec("gpr.traces", self._run_gpr, watchdog_s=None, restart="always"),
            TaskSpec("motion", self._run_motion, watchdog_s=0.5, restart="always"),
            TaskSpec("survey", self.survey.run, watchdog_s=5.0, restart="always"),
            TaskSpec("recorder", self.recorder.run, watchdog_s=5.0, restart="always"),
            TaskSpec("shell.tcp", self._run_shell, watchdog_s=None, restart="always"),
        ]
        tasks.extend(frontends)
        if self.cfg.shell.serial_console:
            tasks.append(TaskSpec("shell.serial", self._run_serial_shell, watchdog_s=None, restart="always"))
        tasks.insert(0, TaskSpec("realsense", self._run_realsense, watchdog_s=None, restart="always"))
        if self.sim is not None:
            tasks.insert(0, TaskSpec("sim.imu", self._run_sim_imu, watchdog_s=1.0, restart="always"))
        if self.worker is not None:
            tasks.append(TaskSpec("worker", self._run_worker_watch, watchdog_s=5.0, restart="always",
                                  critical=False))
        return tasks

    # ----- tasks --------------------------------------------------------------------------------
    async def _run_sim_imu(self, beat: Callable[[], None]) -> None:
        """The simulated IMU: samples of the true motion into the emulated D435i (read back by `realsense`)."""
        assert self.sim is not None
        async for _ in self.sim.feed_imu():
            beat()

    async def _run_realsense(self, beat: Callable[[], None]) -> None:
        assert self.realsense is not None
        next_health, vo_state = self.clock(), "starting"
        async for message in self.realsense.messages():
            beat()
            if isinstance(message, ImuSample):
                self.fusion.submit(message)
                self.recorder.append(message, message.t)
                continue
            self.camera_frames += 1
            self.vo.offer(message)
            if self.cfg.realsense.record_frames:
                self.recorder.append(message, message.t)
            now = self.clock()
            if now >= next_health:  # VO health once a second, for the run log's reader and the operator
                next_health = now + 1.0
                health = self.vo.health()
                self.recorder.append(health, now)
                if health.state != vo_state and health.state != "starting":
                    vo_state = health.state
                    self.emit("vo tracking" if vo_state == "tracking"
                              else f"vo lost ({health.last_failure}); pose from IMU + wheels until it tracks again")

    def _on_vo(self, measurement: VoMeasurement) -> None:
        """A VO measurement (on the loop, from the VO thread): into the filter and the run log."""
        self.fusion.submit(measurement)
        self.recorder.append(measurement, measurement.t)

    async def _stop_vo(self) -> None:
        await asyncio.to_thread(self.vo.stop)

    async def _run_encoders(self, beat: Callable[[], None]) -> None:
        motors = self._motors()
        next_t = self.clock()
        while True:
            beat()
            if motors.connected:
                try:
                    encoders = await motors.read_encoders()
                except DriverError as exc:
                    log.warning("encoder read failed: %s", exc)
                else:
                    self.fusion.submit(encoders.wheel_speeds())
                    self.recorder.append(encoders, encoders.t)
            else:
                # waiting for the driver to reconnect (with backoff) is not a hang: keep beating
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(0.25):
                        await motors.wait_connected()
            next_t = max(next_t + CONTROL_PERIOD_S, self.clock())
            await asyncio.sleep(next_t - self.clock())

    async def _run_gpr(self, beat: Callable[[], None]) -> None:
        assert self.gpr is not None
        async for trace in self.gpr.traces():
            beat()
            self.survey.on_trace(trace)
            self.recorder.append(trace, trace.t)

    async def _run_motion(self, beat: Callable[[], None]) -> None:
        """The 50 Hz motion loop: survey or jog velocity → heading hold → wheel speeds."""
        motors = self._motors()
        last = self.clock()
        while True:
            beat()
            await asyncio.sleep(max(0.0, last + CONTROL_PERIOD_S - self.clock()))
            now = self.clock()
            dt, last = now - last, now
            if self.estopped or self.stopping or not motors.connected:
                self.moving = False
                continue
            jog_velocity = self.jog.update(now)
            survey_velocity = self.survey.velocity
            driving = survey_velocity is not None or self.jog.active
            if not driving:
                if self.moving:  # ramp to a stop (controller accel limit); no heading hold while parked
                    self.moving = False
                    self.drive.wheel_speeds = np.zeros(3)
                    command = WheelSpeeds(now, np.zeros(3))
                    with contextlib.suppress(DriverError):
                        await motors.set_wheel_speeds(command)
                    self.recorder.append(command, now)
                continue
            if not self.moving:
                self.drive.reset(self.fusion.initial_yaw_rad)
                self.drive.wheel_speeds = np.zeros(3)
                self.moving = True
            velocity = survey_velocity if survey_velocity is not None else jog_velocity
            yaw = self.fusion.yaw_rad
            c, s = math.cos(yaw), math.sin(yaw)
            vx, vy = c * velocity[0] + s * velocity[1], -s * velocity[0] + c * velocity[1]  # site → body
            gyro_z = self.fusion.gyro_z_rad_s - self.fusion.gyro_bias_z
            command = self.drive.step(vx, vy, yaw_rad=yaw, gyro_z_rad_s=gyro_z, dt_s=dt, t=now)
            self.last_command = command.speeds
            if self.estopped or self.stopping:  # an e-stop arrived while this step was computed
                continue
            with contextlib.suppress(DriverError):  # the driver stopped the wheels and reconnects
                await motors.set_wheel_speeds(command)
            self.recorder.append(command, now)

    async def start_shell(self) -> None:
        """Load the token and bind the TCP shell (ConfigError if either is impossible)."""
        from gprbot.robot.robot_commands import RobotHandler

        shell = self.cfg.shell
        server = ShellServer(RobotHandler(self), host=self.shell_host, port=self.shell_port,
                             token_file=self.token_file, events=self.events,
                             max_clients=shell.max_clients, rate_per_s=shell.rate_per_s,
                             max_unauthenticated=shell.max_unauthenticated, auth_timeout_s=shell.auth_timeout_s,
                             idle_timeout_s=shell.idle_timeout_s, allow_from=shell.allow_from)
        await server.start()
        self.shell = server
        self.shell_port = server.port

    async def _run_shell(self, beat: Callable[[], None]) -> None:
        """The TCP shell's task: the server (bound at start) serves on the loop; closed in close_devices."""
        beat()
        await asyncio.Event().wait()

    async def _run_serial_shell(self, beat: Callable[[], None]) -> None:
        from gprbot.robot.robot_commands import RobotHandler

        beat()
        assert self.cfg.shell.serial_console is not None
        serial_shell = SerialShell(RobotHandler(self), self.cfg.shell.serial_console,
                                   baudrate=self.cfg.shell.serial_baudrate, events=self.events,
                                   rate_per_s=self.cfg.shell.rate_per_s)
        await serial_shell.start()  # DriverError if the port is absent: the supervisor retries with backoff
        try:
            await asyncio.Event().wait()
        finally:
            await serial_shell.close()

    async def _run_worker_watch(self, beat: Callable[[], None]) -> None:
        while True:
            beat()
            await asyncio.sleep(1.0)

    # ----- operations for the handler --------------------------------------------------------------
    async def estop(self) -> float:
        """Latch the e-stop and command every wheel to 0 now, ahead of queued requests; seconds taken.

        Repeats coalesce: while latched, a stop already in flight is shared, and one confirmed less than
        ESTOP_REPEAT_S ago is not sent again (nothing drives the wheels while latched), so an e-stop
        flood cannot starve the motor bus or flood the clients with events."""
        began = self.clock()
        already = self.estopped
        self.estopped = True
        self.jog.stop(began)
        self.survey.pause()
        if self._estop_stop is not None and not self._estop_stop.done():
            await asyncio.shield(self._estop_stop)
            return self.clock() - began
        if already and began - self._estop_confirmed_t < ESTOP_REPEAT_S:
            return 0.0
        self._estop_stop = asyncio.ensure_future(self.stop_wheels())
        await asyncio.shield(self._estop_stop)
        self._estop_confirmed_t = self.clock()
        if not already:
            self.emit("estop")
        return self.clock() - began

    async def stop_wheels(self) -> None:
        """Stop every wheel now (the controllers' failsafe covers a dead link)."""
        self.moving = False
        self.drive.wheel_speeds = np.zeros(3)
        motors = self._motors()
        if motors.connected:
            await motors.stop()

    def emit(self, event: str) -> None:
        """Broadcast an event line to every shell client."""
        log.info("event: %s", event)
        self.events.broadcast(event)

    def status_text(self) -> str:
        """A one-line summary for systemd's STATUS=."""
        run = self.survey.current
        survey = f"survey {run.state} line {run.line + 1}/{run.lines}" if run is not None else "no survey"
        return f"{'ESTOP' if self.estopped else 'ok'}; {survey}"

    def drivers(self) -> list[Driver]:
        """The started device drivers, all under the one driver contract."""
        started: list[Driver | None] = [self.motors, self.gpr, self.realsense]
        return [d for d in started if d is not None]

    def _links_fault(self) -> str | None:
        """Why the survey cannot go on now (a motor or GPR link down), or None."""
        for driver in (self.motors, self.gpr):
            if driver is not None and not driver.health().connected:
                return f"{driver.health().name} link lost ({driver.health().last_error or 'reconnecting'})"
        return None

    def _motors(self) -> MotorDriver:
        if self.motors is None:
            raise DriverError("the motor driver is not started")
        return self.motors

    def _run_meta(self) -> dict[str, Any]:
        meta: dict[str, Any] = {"simulated": self.sim is not None}
        if self.sim is not None:
            meta["scene"] = self.sim.scene.name
        if self.motors is not None:
            meta["devices"] = {f"roboclaw_{a}": v for a, v in self.motors.firmware.items()}
        return meta
