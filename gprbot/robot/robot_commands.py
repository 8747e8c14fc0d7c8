"""The shell's CommandHandler for the real daemon: status, jog with deadman, stop, e-stop latch, survey.

E-stop: `estop` latches — wheels are commanded to zero at once through the driver's stop path (ahead
of any queued request), the survey is paused, jogs and survey starts are refused — until `reset`.
Jog deadman: a jog lasts while its session keeps sending commands (a repeated `jog`, or `status`)
within `motion.jog_deadman_timeout_s`; the shell answers blank lines itself, so they do not count.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import TYPE_CHECKING

from gprbot.drivers.contract import link_state
from gprbot.drivers.realsense.driver import RealsenseDriver
from gprbot.errors import DriverError, GprbotError
from gprbot.fusion.fuser import FusionStats
from gprbot.messages import VoHealth, expected_rates
from gprbot.shell.commands import ErrorCode, Jog, Reset, Status, Stop, SurveyControl, SurveyStart
from gprbot.shell.handler import RobotCommand, SessionInfo
from gprbot.shell.protocol import Reply

if TYPE_CHECKING:
    from gprbot.robot.runtime import RobotRuntime


class RobotHandler:
    """Executes shell commands against the RobotRuntime; every method returns promptly."""

    def __init__(self, runtime: RobotRuntime) -> None:
        self.rt = runtime
        self._jog_session: int | None = None
        self.last_estop_s: float | None = None

    def runs_dir(self) -> Path:
        """Where the run directories are."""
        return Path(self.rt.cfg.runs_dir)

    async def estop(self, session: SessionInfo) -> Reply:
        """Latch the e-stop and stop the wheels now."""
        try:
            self.last_estop_s = await self.rt.estop()
        except DriverError as exc:
            return Reply.failure(ErrorCode.INTERNAL, f"e-stop latched but the motors did not confirm ({exc}); "
                                 "the controllers' serial timeout stops them — use the hardware e-stop")
        return Reply.success(f"estop latched, wheels stopped in {self.last_estop_s * 1000:.1f} ms; `reset` to clear")

    async def handle(self, command: RobotCommand, session: SessionInfo) -> Reply:
        """Execute one command."""
        rt = self.rt
        if self._jog_session == session.id:
            rt.jog.feed(rt.clock())
        if isinstance(command, Status):
            return Reply.success("status", self.status_lines())
        if isinstance(command, Jog):
            return self._jog(command, session)
        if isinstance(command, Stop):
            rt.jog.stop(rt.clock())
            paused = rt.survey.pause()
            return Reply.success("stopped; survey paused (`survey resume`)" if paused else "stopped")
        if isinstance(command, Reset):
            if not rt.estopped:
                return Reply.success("nothing to reset")
            rt.estopped = False
            rt.emit("estop cleared")
            paused = rt.survey.current is not None and rt.survey.current.state == "paused"
            return Reply.success("reset; survey is paused: `survey resume` or `survey abort`" if paused else "reset")
        if isinstance(command, SurveyStart):
            return self._survey_start(command)
        if isinstance(command, SurveyControl):
            return self._survey_control(command.action)
        return Reply.failure(ErrorCode.BAD_COMMAND, f"{type(command).__name__} is not handled by the robot")

    def _jog(self, command: Jog, session: SessionInfo) -> Reply:
        rt = self.rt
        if rt.estopped:
            return Reply.failure(ErrorCode.ESTOPPED, "e-stop is latched; check the robot, then `reset`")
        if rt.survey.active:
            return Reply.failure(ErrorCode.BUSY, "a survey is running; `survey pause` or `survey abort` first")
        granted = rt.jog.jog(command.vx_m_s, command.vy_m_s, command.seconds, rt.clock())
        self._jog_session = session.id
        return Reply.success(f"jog {granted[0]:.3f} {granted[1]:.3f} {min(command.seconds, rt.jog.max_duration_s):g}"
                             f" (deadman {rt.jog.deadman_timeout_s:g} s)")

    def _survey_start(self, command: SurveyStart) -> Reply:
        rt = self.rt
        if rt.estopped:
            return Reply.failure(ErrorCode.ESTOPPED, "e-stop is latched; check the robot, then `reset`")
        if rt.jog.active:
            return Reply.failure(ErrorCode.BUSY, "a jog is running; `stop` it first")
        base = rt.cfg.survey
        survey = dataclasses.replace(
            base,
            lines=command.lines if command.lines is not None else base.lines,
            spacing_m=command.spacing_m if command.spacing_m is not None else base.spacing_m,
            length_m=command.length_m if command.length_m is not None else base.length_m,
            speed_m_s=command.speed_m_s if command.speed_m_s is not None else base.speed_m_s,
        )
        if survey.speed_m_s > rt.cfg.motion.jog_max_speed_m_s:
            return Reply.failure(ErrorCode.BAD_ARGUMENT,
                                 f"speed {survey.speed_m_s} m/s is above motion.jog_max_speed_m_s "
                                 f"({rt.cfg.motion.jog_max_speed_m_s} m/s)")
        try:
            run = rt.survey.start(survey)
        except GprbotError as exc:
            code = ErrorCode.BUSY if rt.survey.active else ErrorCode.BAD_ARGUMENT
            return Reply.failure(code, str(exc))
        return Reply.success(f"survey {run.name} lines {run.lines} duration {run.plan.duration_s:.1f} s")

    def _survey_control(self, action: str) -> Reply:
        survey = self.rt.survey
        if action == "pause":
            return Reply.success("paused") if survey.pause() else Reply.failure(ErrorCode.BUSY, "no running survey")
        if action == "resume":
            if self.rt.estopped:
                return Reply.failure(ErrorCode.ESTOPPED, "e-stop is latched; `reset` first")
            return Reply.success("resumed") if survey.resume() else Reply.failure(ErrorCode.BUSY, "no paused survey")
        if survey.abort("operator abort"):
            return Reply.success("aborting; finished lines are still reconstructed")
        return Reply.failure(ErrorCode.BUSY, "no survey to abort")

    def status_lines(self) -> list[str]:
        """The `status` body: mode, pose, survey, tasks, drivers, worker."""
        rt = self.rt
        run = rt.survey.current
        mode = "estop" if rt.estopped else "survey" if rt.survey.active else "jog" if rt.jog.active else "idle"
        lines = [f"mode {mode}", f"estop {'latched' if rt.estopped else 'clear'}"]
        pose = rt.fusion.newest_pose()
        if pose is not None:
            lines.append(f"pose {pose.position[0]:.3f} {pose.position[1]:.3f} yaw_deg "
                         f"{math.degrees(rt.fusion.yaw_rad):.2f} t {pose.t:.2f}")
        else:
            lines.append("pose none (filter initialising)")
        if run is not None:
            lines.append(f"survey {run.name} {run.state} line {run.line + 1}/{run.lines} traces {len(run.traces)}"
                         + (f" pipes {run.pipes}" if run.pipes is not None else "")
                         + (f" interrupted_lines {sorted({line for line, _ in run.interruptions})}"
                            if run.interruptions else "")
                         + (f" error {run.error}" if run.error else ""))
        if rt.supervisor is not None:
            lines.append(f"supervisor {'healthy' if rt.supervisor.healthy else 'UNHEALTHY'} "
                         f"loop_lag_ms {rt.supervisor.loop_lag_s * 1000:.1f}")
            for task in rt.supervisor.health():
                lines.append(f"task {task.name} {task.state} restarts {task.restarts}"
                             + (f" last_error {task.last_error}" if task.last_error else ""))
        expected = expected_rates(rt.cfg)
        healths = []
        for driver in rt.drivers():  # a camera's streams each on a line of their own
            healths += list(driver.streams().values()) if isinstance(driver, RealsenseDriver) else [driver.health()]
        for h in healths:
            slow = h.slow_against(expected.get(h.name))
            lines.append(f"driver {h.name} {link_state(h).value} rate_hz "
                         f"{h.rate_hz:.1f} drops {h.drops} errors {h.errors}"
                         + (f" SLOW expected_hz {expected[h.name]:.1f}" if slow else ""))
        lines.append(vo_status_line(rt.vo.health(), rt.fusion.fuser.stats))
        if rt.worker is not None:
            w = rt.worker.health()
            lines.append(f"worker {'alive' if w.alive else 'down'} busy {w.busy} jobs {w.jobs_done} "
                         f"failed {w.jobs_failed} restarts {w.restarts}")
        lines.append(f"recorder {'recording ' + str(rt.recorder.run_dir) if rt.recorder.recording else 'idle'}")
        if rt.web is not None:
            lines.append(f"web {rt.web.url} browsers {rt.web.browser_count}")
        elif rt.web_error:
            lines.append(f"web DOWN {rt.web_error}")
        return lines


def vo_status_line(vo: VoHealth, stats: FusionStats) -> str:
    """VO's health and what the filter did with it, on one `status` line."""
    line = (f"vo {vo.state} features {vo.features} tracked {vo.tracked} inlier_ratio {vo.inlier_ratio:.2f} "
            f"rate_hz {vo.rate_hz:.1f} latency_ms {vo.latency_ms_median:.0f} max {vo.latency_ms_max:.0f} "
            f"frames {vo.frames} dropped {vo.dropped} lost_frames {vo.lost_frames} "
            f"fused {stats.vo_updates} rejected {stats.vo_rejected} late {stats.late_dropped} "
            f"map_keyframes {vo.map_keyframes} revisits {vo.revisits}/{vo.revisit_attempts} "
            f"fused {stats.revisit_updates} rejected {stats.revisit_rejected}")
    if vo.state == "lost":
        line += f" (pose from IMU + wheels: {vo.last_failure})"
    return line
