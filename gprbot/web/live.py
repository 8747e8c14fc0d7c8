"""What the console's WebSocket carries: status snapshots, the current line's traces, finished lines.

`LiveFeed.poll()` looks at the running survey (the runner's traces, line windows, B-scans and the
worker's per-line previews) and returns the messages that are new since the last poll; the server
sends the same messages to every browser. Traces are decimated for the screen: samples are averaged
in blocks down to at most `MAX_SAMPLES` (the GPR samples ~40 GHz for a ~1 GHz antenna, so block means
of a few samples lose nothing visible) and traces are stacked when they come faster than the browser
needs. Amplitudes travel as int16 with one scale per batch; gain and colour are applied in the page.
"""

from __future__ import annotations

import math
import shutil
from collections import deque
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from gprbot.geometry import antenna_xy
from gprbot.messages import Trace
from gprbot.outputs.run_document import b64

if TYPE_CHECKING:
    from gprbot.robot.runtime import RobotRuntime
    from gprbot.robot.survey_runner import SurveyRun

MAX_SAMPLES = 256
SECTION_MAX_W, SECTION_MAX_H = 320, 160
MAX_TRACK_POINTS = 200
MAX_SLICE_POINTS = 400
Message = dict[str, Any]


def decimate_samples(data: NDArray[np.float32], max_samples: int = MAX_SAMPLES) -> tuple[NDArray[np.float32], int]:
    """Block means along the samples axis (traces × samples) down to ≤ max_samples; and the factor."""
    factor = max(1, math.ceil(data.shape[1] / max_samples))
    usable = data.shape[1] // factor * factor
    return data[:, :usable].reshape(len(data), -1, factor).mean(axis=2, dtype=np.float32), factor


def stack_traces(data: NDArray[np.float32], group: int) -> NDArray[np.float32]:
    """Means of `group` consecutive traces (a last partial group is averaged on its own)."""
    if group <= 1:
        return data
    starts = np.arange(0, len(data), group)
    sums = np.add.reduceat(data, starts, axis=0)
    return (sums / np.diff(np.append(starts, len(data)))[:, None]).astype(np.float32)


def quantise(data: NDArray[np.float32]) -> tuple[NDArray[np.int16], float]:
    """int16 amplitudes and the scale (mV per count) that restores them."""
    peak = float(np.max(np.abs(data))) if data.size else 0.0
    scale = peak / 32767.0 if peak > 0 else 1.0
    return np.round(data / scale).astype(np.int16), scale


def section_picture(image: NDArray[np.floating], max_w: int = SECTION_MAX_W, max_h: int = SECTION_MAX_H
                    ) -> NDArray[np.uint8]:
    """A migrated image (z, x) as 8-bit magnitude, block-max reduced to the screen, clipped at the 99.5th pct."""
    magnitude = np.abs(np.asarray(image, dtype=np.float32))
    fz = max(1, math.ceil(magnitude.shape[0] / max_h))
    fx = max(1, math.ceil(magnitude.shape[1] / max_w))
    h, w = magnitude.shape[0] // fz * fz, magnitude.shape[1] // fx * fx
    reduced = magnitude[:h, :w].reshape(h // fz, fz, w // fx, fx).max(axis=(1, 3))
    top = float(np.percentile(reduced, 99.5)) if reduced.size else 0.0
    picture: NDArray[np.uint8] = np.clip(255.0 * reduced / (top or 1.0), 0, 255).astype(np.uint8)
    return picture


def thin(points: NDArray[np.float64], limit: int) -> NDArray[np.float64]:
    """Every k-th row so that at most `limit` remain (first and last kept)."""
    if len(points) <= limit:
        return points
    index = np.unique(np.linspace(0, len(points) - 1, limit).round().astype(int))
    kept: NDArray[np.float64] = points[index]
    return kept


class LiveFeed:
    """The console's live messages, built from the runtime's state; one instance per console."""

    def __init__(self, runtime: RobotRuntime) -> None:
        self.rt = runtime
        self._run: str | None = None
        self._next_trace = 0
        self._line_counts: dict[int, int] = {}
        self._lines_sent: dict[int, bool] = {}  # line → whether its message had the worker's section
        self._done_sent = False
        self._base: deque[tuple[float, float, float]] = deque(maxlen=32)  # (t, x, y) of the base, per status
        self._speed = 0.0
        self._antenna: deque[tuple[float, float, float]] = deque(maxlen=64)  # (t, x, y) of the antenna
        self._line_origin: dict[int, NDArray[np.float64]] = {}
        self.backlog: list[Message] = []  # everything sent about the current run, for a browser joining late

    # ----- messages -----------------------------------------------------------------------------
    def hello(self) -> Message:
        """The first message to a browser: the settings the page needs to draw and validate."""
        cfg = self.rt.cfg
        return {"type": "hello", "gpr": {"samples": cfg.gpr.samples, "dt_ns": cfg.gpr.dt_ns,
                                          "pre_trigger_ns": cfg.gpr.pre_trigger_ns,
                                          "frequency_mhz": cfg.gpr.centre_frequency_mhz},
                "survey": {"lines": cfg.survey.lines, "spacing_m": cfg.survey.spacing_m,
                           "length_m": cfg.survey.length_m, "speed_m_s": cfg.survey.speed_m_s,
                           "start_xy_m": list(cfg.survey.start_xy_m), "trace_rate_hz": cfg.survey.trace_rate_hz},
                "jog": {"max_speed_m_s": cfg.motion.jog_max_speed_m_s,
                        "deadman_s": cfg.motion.jog_deadman_timeout_s},
                "lever_arm_m": list(cfg.mount.antenna_lever_arm_m[:2]), "simulated": self.rt.sim is not None}

    def status(self, clients: int) -> Message:
        """Pose, speed, heading, device and task health, survey progress, disk left."""
        rt = self.rt
        pose = rt.fusion.newest_pose()
        pose_record = None
        if pose is not None:
            x, y, z = (float(v) for v in pose.position)
            self._base.append((pose.t, x, y))
            # speed over the last second of poses: a one-tick difference jumps with every filter correction
            recent = [b for b in self._base if b[0] >= pose.t - 1.0]
            if len(recent) >= 2 and recent[-1][0] > recent[0][0]:
                (t0, x0, y0), (t1, x1, y1) = recent[0], recent[-1]
                self._speed = math.hypot(x1 - x0, y1 - y0) / (t1 - t0)
            pose_record = {"x": round(x, 4), "y": round(y, 4), "z": round(z, 4),
                           "yaw_deg": round(math.degrees(rt.fusion.yaw_rad), 2)}
        devices = []
        for driver in (rt.motors, rt.gpr):
            if driver is not None:
                h = driver.health()
                detail = f"{h.rate_hz:.0f} Hz, {h.drops} drops, {h.errors} errors"
                if h.last_error and not h.connected:
                    detail += f", {h.last_error}"
                devices.append({"name": h.name, "ok": h.connected, "detail": detail})
        if rt.sim is not None:
            devices.append({"name": "imu (simulated)", "ok": rt.fusion.ready, "detail": "ready" if rt.fusion.ready
                            else "initialising"})
        elif rt.realsense is not None:
            devices.append({"name": "realsense", "ok": rt.fusion.ready, "detail": f"{rt.camera_frames} frames"})
        if rt.worker is not None:
            w = rt.worker.health()
            devices.append({"name": "inference worker", "ok": w.alive,
                            "detail": f"{'busy' if w.busy else 'idle'}, {w.jobs_done} jobs, {w.jobs_failed} failed"})
        tasks = [{"name": t.name, "state": t.state, "restarts": t.restarts}
                 for t in (rt.supervisor.health() if rt.supervisor is not None else [])]
        run = rt.survey.current
        survey = None if run is None else {
            "name": run.name, "state": run.state, "line": run.line, "lines": run.lines, "traces": len(run.traces),
            "lines_done": len(run.bscans), "pipes": run.pipes, "error": run.error}
        try:
            disk = shutil.disk_usage(rt.cfg.runs_dir)
            disk_record = {"free_gb": round(disk.free / 1e9, 2), "total_gb": round(disk.total / 1e9, 2)}
        except OSError:
            disk_record = None
        mode = "estop" if rt.estopped else "survey" if rt.survey.active else "jog" if rt.jog.active else "idle"
        return {"type": "status", "mode": mode, "estop": rt.estopped, "pose": pose_record,
                "speed_m_s": round(self._speed, 3), "heading_deg": pose_record["yaw_deg"] if pose_record else None,
                "devices": devices, "tasks": tasks, "survey": survey, "disk": disk_record,
                "healthy": rt.supervisor.healthy if rt.supervisor is not None else None,
                "recording": rt.recorder.recording, "clients": clients}

    def poll(self, max_traces: int) -> list[Message]:
        """The messages new since the last poll: a new run, traces of the current line, finished lines."""
        run = self.rt.survey.current
        if run is None:
            return []
        out: list[Message] = []
        if run.name != self._run:
            self._run, self._next_trace, self._done_sent = run.name, 0, False
            self._line_counts.clear()
            self._line_origin.clear()
            self._lines_sent.clear()
            self.backlog = []
            out.append({"type": "run", "run": run.name, "lines": run.lines, "survey": {
                "lines": run.survey.lines, "spacing_m": run.survey.spacing_m, "length_m": run.survey.length_m,
                "speed_m_s": run.survey.speed_m_s, "start_xy_m": list(run.survey.start_xy_m)}})
        out += self._new_traces(run, max_traces)
        out += self._finished_lines(run)
        if not self._done_sent and run.state in ("done", "aborted", "failed") and not self.rt.survey.active:
            self._done_sent = True
            out.append({"type": "survey_end", "run": run.name, "state": run.state, "pipes": run.pipes,
                        "error": run.error})
        self.backlog += out
        return out

    # ----- pieces -------------------------------------------------------------------------------
    def _line_of(self, run: SurveyRun, trace: Trace) -> int | None:
        """The line a trace belongs to (None: recorded between lines)."""
        for line in (run.line, run.line - 1):
            if any(a <= trace.t and (math.isnan(b) or trace.t <= b) for a, b in run.windows.get(line, ())):
                return line
        return None

    def _sample_antenna(self) -> None:
        """Keep the antenna's newest fused position (base pose + lever arm), for the traces' distances."""
        pose = self.rt.fusion.newest_pose()
        if pose is None or (self._antenna and self._antenna[-1][0] >= pose.t):
            return
        x, y = antenna_xy(pose, self.rt.cfg.mount.antenna_lever_arm_m)
        self._antenna.append((pose.t, float(x), float(y)))

    def _distances(self, line: int, times: NDArray[np.float64]) -> NDArray[np.float64]:
        """Each trace's distance from the line's first trace, from the fused poses (the newest traces,
        which the filter has not covered yet, get its newest position: a lag of its reorder window)."""
        if len(self._antenna) < 2:
            return np.zeros(len(times))
        t, x, y = (np.array(c) for c in zip(*self._antenna, strict=True))
        xy = np.column_stack([np.interp(times, t, x), np.interp(times, t, y)])
        origin = self._line_origin.setdefault(line, xy[0])
        distances: NDArray[np.float64] = np.hypot(*(xy - origin).T)
        return distances

    def _new_traces(self, run: SurveyRun, max_traces: int) -> list[Message]:
        new = run.traces[self._next_trace:]
        self._next_trace += len(new)
        self._sample_antenna()
        by_line: dict[int, list[Trace]] = {}
        for trace in new:
            line = self._line_of(run, trace)
            if line is not None:
                by_line.setdefault(line, []).append(trace)
        out = []
        for line, traces in sorted(by_line.items()):
            data = np.stack([np.asarray(tr.samples, dtype=np.float32) for tr in traces])
            group = max(1, math.ceil(len(data) / max(max_traces, 1)))
            data = stack_traces(data, group)
            distances = self._distances(line, np.array([tr.t for tr in traces]))
            along = stack_traces(distances.astype(np.float32)[:, None], group)[:, 0]
            data, factor = decimate_samples(data)
            counts, scale = quantise(data)
            first = self._line_counts.get(line, 0)
            self._line_counts[line] = first + len(counts)
            out.append({"type": "traces", "run": run.name, "line": line, "first": first, "n": len(counts),
                        "samples": counts.shape[1], "dt_ns": self.rt.cfg.gpr.dt_ns * factor,
                        "t0_ns": self.rt.cfg.gpr.pre_trigger_ns, "scale": scale,
                        "x_m": [round(float(x), 4) for x in along], "data": b64(counts)})
        return out

    def _finished_lines(self, run: SurveyRun) -> list[Message]:
        out = []
        for line, bscan in sorted(run.bscans.items()):
            preview = run.previews.get(line)
            if self._lines_sent.get(line) is True or (line in self._lines_sent and preview is None):
                continue
            self._lines_sent[line] = preview is not None
            message: Message = {"type": "line", "run": run.name, "line": line,
                                "track": thin(bscan.positions[:, :2], MAX_TRACK_POINTS).round(4).tolist(),
                                "traces": len(bscan.data)}
            if preview is not None:
                section = preview.section
                picture = section_picture(section.image)
                detections = []
                for d in section.detections:
                    x, y, _ = (float(c) for c in bscan.position_at(d.x_m))
                    detections.append({"along_m": round(d.x_m, 4), "depth_m": round(d.depth_m, 4),
                                       "radius_m": round(d.radius_m, 4),
                                       "confidence": round(d.score, 3), "x_m": round(x, 4), "y_m": round(y, 4)})
                message["section"] = {"w": picture.shape[1], "h": picture.shape[0], "data": b64(picture),
                                      "x0": float(section.x_m[0]), "x1": float(section.x_m[-1]),
                                      "z0": float(section.z_m[0]), "z1": float(section.z_m[-1]),
                                      "velocity_m_per_ns": round(preview.velocity_m_per_ns, 4),
                                      "velocity_source": preview.velocity_source}
                message["detections"] = detections
                message["slice_xyz"] = thin(preview.slice.points, MAX_SLICE_POINTS).round(4).tolist()
            out.append(message)
        return out
