"""Drives a survey online: plan → velocity for the motion loop, line events, traces per line, outputs.

The runner walks the planner's segments in real time and publishes the site-frame velocity the motion
loop should drive (heading hold adds ω there). Each line's time windows (a pause splits a line) select
its traces; once the filter's poses cover a finished line it is assembled into a B-scan and handed to
the inference worker for a preview while the next line is driven. At the end the worker reconstructs
the whole survey and the run directory gets the same files as `gprbot demo` writes.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from gprbot.config import Config, SurveyConfig, to_dict
from gprbot.errors import GprbotError
from gprbot.gpr.bscan import BScan
from gprbot.infer.pipeline import reconstruct_survey
from gprbot.infer.worker import InferenceWorker
from gprbot.infer.worker_process import LineJobResult
from gprbot.messages import SurveyEvent, Trace
from gprbot.motion.planner import Segment, SurveyPlan, plan_survey, survey_region
from gprbot.outputs.report_html import write_report_safely
from gprbot.outputs.run_dir import write_survey_outputs
from gprbot.reconstruct.survey_result import SurveyResult
from gprbot.retention import prune_runs
from gprbot.robot.fusion_state import FusionState
from gprbot.robot.recorder import Recorder
from gprbot.robot.tracking import tracking_velocity
from gprbot.runlog import make_run_header
from gprbot.survey import assemble_bscan

log = logging.getLogger(__name__)
STEP_S = 0.02  # how often the runner re-checks pause/abort while a segment runs
LINK_RESUME_S = 10.0  # a survey paused by a lost device link resumes by itself if it is back within this
LINK_SETTLE_S = 0.3
T = TypeVar("T")


@dataclass
class SurveyRun:
    """One survey being driven (or just finished): its plan, progress, traces and line B-scans."""

    name: str
    run_dir: Path
    survey: SurveyConfig
    plan: SurveyPlan
    state: str = "starting"  # starting | running | paused | finishing | done | aborted | failed
    line: int = -1
    windows: dict[int, list[list[float]]] = field(default_factory=dict)
    traces: list[Trace] = field(default_factory=list)
    bscans: dict[int, BScan] = field(default_factory=dict)
    previews: dict[int, LineJobResult] = field(default_factory=dict)  # the worker's per-line interpretation
    pipes: int | None = None
    error: str | None = None
    abort_reason: str | None = None
    interruptions: list[tuple[int, str]] = field(default_factory=list)  # (line, why): a device link was lost
    paused_by_link: str | None = None

    @property
    def lines(self) -> int:
        """How many lines the plan has."""
        return len(self.plan.lines())


class SurveyRunner:
    """Executes one survey at a time; the handler starts, pauses, resumes and aborts it."""

    def __init__(self, cfg: Config, fusion: FusionState, recorder: Recorder, emit: Callable[[str], None], *,
                 worker: InferenceWorker | None = None, clock: Callable[[], float] = time.monotonic,
                 run_meta: Callable[[], dict[str, Any]] | None = None,
                 truth_axes: list[NDArray[np.float64]] | None = None,
                 links_fault: Callable[[], str | None] | None = None,
                 may_resume: Callable[[], bool] | None = None) -> None:
        self.cfg, self.fusion, self.recorder, self.emit = cfg, fusion, recorder, emit
        self.links_fault = links_fault or (lambda: None)  # why a device link is down, or None
        self.may_resume = may_resume or (lambda: True)
        self.worker, self.clock = worker, clock
        self.run_meta = run_meta or dict
        self.truth_axes = truth_axes or []
        self.current: SurveyRun | None = None
        self.velocity: NDArray[np.float64] | None = None  # site-frame velocity to drive; None: not driving
        self._pending: asyncio.Queue[SurveyRun] = asyncio.Queue(maxsize=1)
        self._resumed = asyncio.Event()
        self._resumed.set()
        self._line_jobs: list[asyncio.Task[None]] = []
        self._idle = asyncio.Event()
        self._idle.set()
        self._skip_outputs = False

    # ----- commands -----------------------------------------------------------------------------
    @property
    def active(self) -> bool:
        """Whether a survey is starting, running, paused or finishing."""
        return self.current is not None and self.current.state in ("starting", "running", "paused", "finishing")

    def start(self, survey: SurveyConfig) -> SurveyRun:
        """Queue a survey (ConfigError for a bad plan, GprbotError while another one runs)."""
        if self.active or not self._pending.empty():
            raise GprbotError("a survey is already running; `survey abort` it first")
        plan = plan_survey(survey)
        stem = time.strftime("%Y%m%d-%H%M%S-survey")
        name, copy = stem, 1
        while (Path(self.cfg.runs_dir) / name).exists():  # two starts within a second
            copy += 1
            name = f"{stem}{copy}"
        run = SurveyRun(name, Path(self.cfg.runs_dir) / name, survey, plan)
        self.current = run
        self._idle.clear()
        self._pending.put_nowait(run)
        return run

    def pause(self) -> bool:
        """Hold the survey where it is (wheels to zero); whether a running survey was paused."""
        run = self.current
        if run is None or run.state != "running":
            return False
        run.state = "paused"
        run.paused_by_link = None
        self.velocity = None
        self._resumed.clear()
        self.emit(f"survey paused {run.name} line {run.line}")
        return True

    def _pause_for_link(self, run: SurveyRun, line: int, fault: str) -> None:
        """A device link went down mid-survey: hold (the wheels are stopped anyway) and resume by itself if
        the link is back within LINK_RESUME_S — otherwise the survey's clock would run on with the robot
        standing still, shortening the line (what made results depend on the machine's load)."""
        if not self.pause():
            return
        run.paused_by_link = fault
        run.interruptions.append((line, fault))
        self.emit(f"survey line {line} interrupted: {fault}; resuming when the link is back")
        self._line_jobs.append(asyncio.create_task(self._resume_when_linked(run)))

    async def _resume_when_linked(self, run: SurveyRun) -> None:
        deadline = self.clock() + LINK_RESUME_S
        while run.state == "paused" and run.paused_by_link is not None:
            if self.links_fault() is None and self.may_resume():
                await asyncio.sleep(LINK_SETTLE_S)  # the filter catches up with the reconnected sensors
                if run.state == "paused" and run.paused_by_link is not None and self.links_fault() is None:
                    run.paused_by_link = None
                    self.resume()
                return
            if self.clock() > deadline:
                self.emit(f"survey {run.name}: link still down after {LINK_RESUME_S:g} s; `survey resume` once fixed")
                return
            await asyncio.sleep(0.05)

    def resume(self) -> bool:
        """Continue a paused survey; whether one was paused."""
        run = self.current
        if run is None or run.state != "paused":
            return False
        run.state = "running"
        self._resumed.set()
        self.emit(f"survey resumed {run.name}")
        return True

    def abort(self, reason: str = "abort") -> bool:
        """End the survey after the current instant; finished lines are still reconstructed."""
        run = self.current
        if run is None or run.state not in ("starting", "running", "paused"):
            return False
        run.abort_reason = reason
        self.velocity = None
        self._resumed.set()
        return True

    async def shutdown(self, timeout_s: float = 5.0) -> None:
        """End the current line, close the run log, skip the reconstruction (daemon shutdown)."""
        self._skip_outputs = True
        self.abort("shutdown")
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(timeout_s):
                await self._idle.wait()

    def on_trace(self, trace: Trace) -> None:
        """Keep a trace of the running survey (the line windows select them later)."""
        run = self.current
        if run is not None and run.state in ("running", "paused"):
            run.traces.append(trace)

    # ----- the survey task ----------------------------------------------------------------------
    async def run(self, beat: Callable[[], None]) -> None:
        """The survey task: wait for a start, drive it, produce its outputs; repeat."""
        while True:
            beat()
            try:
                async with asyncio.timeout(0.5):  # not wait_for: on 3.11 it can swallow a cancel
                    survey = await self._pending.get()
            except TimeoutError:
                continue
            try:
                await self._execute(survey, beat)
            except GprbotError as exc:  # the data or a device, not this task: the survey fails, the task goes on
                survey.state, survey.error = "failed", f"{type(exc).__name__}: {exc}"
                log.error("survey %s failed: %s", survey.name, exc)
                self.emit(f"survey failed {survey.name}: {exc}")
            except Exception as exc:  # a bug: the supervisor restarts the task (and counts it)
                survey.state, survey.error = "failed", f"{type(exc).__name__}: {exc}"
                self.emit(f"survey failed {survey.name}: {exc}")
                raise
            finally:
                self.velocity = None
                for job in self._line_jobs:
                    job.cancel()
                self._line_jobs.clear()
                await self.recorder.close({"run": survey.name, "state": survey.state})
                self._idle.set()

    async def _execute(self, run: SurveyRun, beat: Callable[[], None]) -> None:
        header = make_run_header(self.cfg, time.time(), run=run.name, kind="survey",
                                 survey=to_dict(run.survey), **self.run_meta())
        self.recorder.open(run.run_dir, header)
        # Replay continues this filter. The snapshot goes in the same step as the open, with no await
        # between: a sensor message logged before it would be pushed twice on replay (once inside the
        # snapshot's state, once from the log); on a loaded machine the prune below let dozens in.
        self.recorder.append(self.fusion.snapshot(self.clock()), self.clock())
        # Old runs beyond the configured limits go now, before this one fills the disk (off the event loop).
        pruned = await asyncio.to_thread(prune_runs, Path(self.cfg.runs_dir), self.cfg.retention, {run.name})
        if pruned:
            self.emit(f"retention: deleted {len(pruned)} old runs ({', '.join(r.name for r in pruned)})")
        await self._beating(self._wait_fusion(), beat)
        if run.abort_reason is None:
            run.state = "running"
            self._event(run, "survey_start", -1, f"survey started {run.name} lines {run.lines}")
            # A replay re-runs the pose filter from the log's start: it needs the robot at rest for the
            # filter's initialisation before line 0 begins, whatever the plan's own settle time.
            hold_s = self.cfg.fusion.init_duration_s + 0.2 - run.survey.settle_s
            if hold_s > 0:
                await self._beating(asyncio.sleep(hold_s), beat)
            t_plan = self.clock()
            for segment in run.plan.segments:
                await self._drive(run, segment, beat)
                if run.abort_reason is not None:
                    break
            log.info("survey %s drove its plan in %.1f s", run.name, self.clock() - t_plan)
        self.velocity = None
        run.state = "finishing"
        await self._beating(asyncio.gather(*self._line_jobs, return_exceptions=True), beat)
        self._event(run, "abort" if run.abort_reason else "survey_end", -1,
                    f"survey {'aborted (' + run.abort_reason + ')' if run.abort_reason else 'driven'} {run.name}")
        await self.recorder.close({"run": run.name, "lines": sorted(run.bscans), "traces": len(run.traces),
                                   "aborted": run.abort_reason,
                                   "interrupted_lines": [[line, why] for line, why in run.interruptions]})
        if self._skip_outputs or not run.bscans:
            run.state = "aborted" if run.abort_reason else "done"
            return
        result = await self._beating(self._reconstruct(run.bscans), beat)
        for line, why in result.skipped_lines.items():
            self.emit(f"line {line} left out of the results: {why}")
        await self._write_outputs(run, result, beat)
        run.pipes = len(result.reconstruction.pipes)
        run.state = "aborted" if run.abort_reason else "done"
        self.emit(f"survey done {run.name} pipes {run.pipes}")

    async def _write_outputs(self, run: SurveyRun, result: SurveyResult, beat: Callable[[], None]) -> None:
        """The run directory's results, written by the inference worker (or a thread without one); a picture per
        line and the exports take seconds, so the survey task's watchdog is fed meanwhile (a restart would lose
        the results)."""
        meta = {"run": run.name, "frame": "site: x forward along the survey lines, y left, z up; metres",
                "source": "gprbot run", "config": to_dict(self.cfg), **self.run_meta()}
        s = run.survey
        extent = survey_region(s.start_xy_m, s.length_m, s.lines, s.spacing_m, 0.2, 0.2)
        if self.worker is not None:  # the worker process: matplotlib holds the GIL for seconds per picture
            writing: Awaitable[Any] = self.worker.write_outputs(run.run_dir, result, meta, extent, self.truth_axes,
                                                                run.bscans)
        else:
            writing = asyncio.to_thread(write_survey_outputs, run.run_dir, result, meta, extent, self.truth_axes,
                                        raw_lines=run.bscans)
        await self._beating(writing, beat)
        await self._beating(asyncio.to_thread(write_report_safely, run.run_dir), beat)  # the offline report.html

    async def _drive(self, run: SurveyRun, segment: Segment, beat: Callable[[], None]) -> None:
        """Drive one segment for its planned duration (pauses excluded)."""
        is_line = segment.kind == "line"
        if is_line:
            run.line = segment.line
            run.windows[segment.line] = [[self.clock(), float("nan")]]
            self._event(run, "line_start", segment.line, f"line {segment.line} start")
        duration = segment.t_end - segment.t_start
        remaining = duration
        while remaining > 1e-6 and run.abort_reason is None:
            beat()
            if run.state == "paused":
                if is_line:
                    run.windows[segment.line][-1][1] = self.clock()
                await self._beating(self._resumed.wait(), beat)
                if is_line and run.abort_reason is None:
                    run.windows[segment.line].append([self.clock(), float("nan")])
                continue
            fault = self.links_fault()
            if fault is not None:
                self._pause_for_link(run, segment.line if is_line else -1, fault)
                continue
            began = self.clock()
            self.velocity = tracking_velocity(segment, duration - remaining, began, self.fusion.newest_pose(),
                                              self.cfg.mount.antenna_lever_arm_m)
            await asyncio.sleep(min(remaining, STEP_S))
            remaining -= self.clock() - began
        self.velocity = np.zeros(2)
        if is_line:
            window = run.windows[segment.line][-1]
            if np.isnan(window[1]):
                window[1] = self.clock()
            self._event(run, "line_end", segment.line, f"line {segment.line} end")
            self._line_jobs.append(asyncio.create_task(self._finish_line(run, segment.line)))

    async def _finish_line(self, run: SurveyRun, line: int) -> None:
        """Assemble a finished line once the poses cover it; preview it in the worker."""
        windows = [(a, b) for a, b in run.windows[line] if b > a]
        if not windows:
            return
        end = windows[-1][1]
        for _ in range(100):  # the filter's output trails the sensors by its reorder window
            newest = self.fusion.newest_pose()
            if newest is not None and newest.t >= end:
                break
            await asyncio.sleep(0.05)
        traces = [tr for tr in run.traces if any(a <= tr.t <= b for a, b in windows)]
        poses = self.fusion.poses_between(windows[0][0], end)
        if len(traces) < 2 or len(poses) < 2:
            log.warning("line %d has %d traces and %d poses; skipped", line, len(traces), len(poses))
            return
        run.bscans[line] = await asyncio.to_thread(assemble_bscan, traces, poses, self.cfg.mount.antenna_lever_arm_m)
        self.emit(f"line {line} assembled traces {len(traces)}")
        if self.worker is not None and not self._skip_outputs:
            try:
                preview = await self.worker.interpret_line(line, run.bscans[line], None)
            except GprbotError as exc:
                log.warning("preview of line %d failed: %s", line, exc)
                return
            run.previews[line] = preview
            self.emit(f"line {line} preview velocity {preview.velocity_m_per_ns:.4f} m/ns")

    async def _reconstruct(self, bscans: dict[int, BScan]) -> SurveyResult:
        if self.worker is not None:
            return await self.worker.finish_survey(dict(bscans))
        return await asyncio.to_thread(reconstruct_survey, dict(bscans), self.cfg,
                                       np.random.default_rng(self.cfg.reconstruction_seed))

    async def _wait_fusion(self, timeout_s: float = 10.0) -> None:
        deadline = self.clock() + timeout_s
        while not self.fusion.ready:
            if self.clock() > deadline:
                raise GprbotError("the pose filter is not ready (no IMU data?); check `status` and the sensors")
            await asyncio.sleep(0.05)

    def _event(self, run: SurveyRun, kind: str, line: int, text: str) -> None:
        now = self.clock()
        self.recorder.append(SurveyEvent(now, kind, line), now)
        self.emit(text)

    async def _beating(self, awaitable: Awaitable[T], beat: Callable[[], None], every_s: float = 0.5) -> T:
        """Await something long while still feeding this task's watchdog."""
        task = asyncio.ensure_future(awaitable)
        try:
            while True:
                done, _ = await asyncio.wait({task}, timeout=every_s)
                beat()
                if done:
                    return task.result()
        finally:
            task.cancel()
