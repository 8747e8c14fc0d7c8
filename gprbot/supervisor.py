"""The declared table of tasks and the one supervisor that starts, watches and restarts them.

Each TaskSpec names a task, the coroutine factory that runs it, its watchdog deadline (the task calls
the `beat` it is given at least that often, or it counts as hung and is restarted) and its restart
policy. The supervisor restarts failed tasks with exponential backoff, publishes per-task health for
`status`, and speaks to systemd: READY=1 once every task runs, STATUS= lines on change, WATCHDOG=1
only while its own loop keeps time and no critical task is down for good (STOPPING=1 is the daemon's).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal

from gprbot.backoff import Backoff
from gprbot.errors import GprbotError
from gprbot.sdnotify import SdNotifier, watchdog_interval_s

log = logging.getLogger(__name__)

RestartPolicy = Literal["always", "on-failure", "never"]
TaskFactory = Callable[[Callable[[], None]], Awaitable[None]]
BACKOFF_S = (0.1, 5.0)  # first and longest wait before restarting a failed task
STABLE_AFTER_S = 10.0  # a task that ran this long before failing restarts from the first backoff again


@dataclass(frozen=True)
class TaskSpec:
    """One row of the task table: the factory gets a `beat()` to call at least every `watchdog_s`."""

    name: str
    factory: TaskFactory
    watchdog_s: float | None = None
    restart: RestartPolicy = "on-failure"
    critical: bool = True  # while it is down for good, systemd's watchdog is not fed


@dataclass(frozen=True)
class TaskHealth:
    """A task's published health."""

    name: str
    state: str  # "running" | "backoff" | "done" | "failed" | "stopped"
    restarts: int
    last_error: str | None
    beat_age_s: float | None


@dataclass
class _TaskRecord:
    spec: TaskSpec
    task: asyncio.Task[None] | None = None
    state: str = "stopped"
    restarts: int = 0
    last_error: str | None = None
    started_t: float = 0.0
    last_beat_t: float = 0.0
    backoff: Backoff = field(default_factory=lambda: Backoff(*BACKOFF_S))
    restart_at: float = math.inf


class Supervisor:
    """Runs the task table: start, watchdog, restart with backoff, health, systemd notifications."""

    def __init__(self, specs: Sequence[TaskSpec], notifier: SdNotifier | None = None, *,
                 clock: Callable[[], float] = time.monotonic, tick_s: float = 0.1,
                 backoff_s: tuple[float, float] = BACKOFF_S, max_loop_lag_s: float = 1.0,
                 status_text: Callable[[], str] | None = None) -> None:
        names = [s.name for s in specs]
        if len(set(names)) != len(names):
            raise GprbotError(f"task names must be unique, got {names}")
        self._records = {s.name: _TaskRecord(s, backoff=Backoff(*backoff_s)) for s in specs}
        self.notifier = notifier or SdNotifier()
        self._clock = clock
        self.tick_s = tick_s
        self._max_lag_s = max_loop_lag_s
        self._status_text = status_text
        self._last_status = ""
        self._cancelling: set[asyncio.Task[None]] = set()
        self.ready = False
        self.healthy = True
        self.loop_lag_s = 0.0

    # ----- the task table -------------------------------------------------------------------------
    def start(self) -> None:
        """Start every task (in table order)."""
        for record in self._records.values():
            self._launch(record)

    def beat(self, name: str) -> None:
        """Task `name` is alive (its watchdog deadline restarts from now)."""
        self._records[name].last_beat_t = self._clock()

    def health(self) -> list[TaskHealth]:
        """Every task's health, in table order."""
        now = self._clock()
        return [TaskHealth(r.spec.name, r.state, r.restarts, r.last_error,
                           now - r.last_beat_t if r.state == "running" else None) for r in self._records.values()]

    def _launch(self, record: _TaskRecord) -> None:
        now = self._clock()
        record.started_t = record.last_beat_t = now
        record.state, record.restart_at = "running", math.inf
        record.task = asyncio.create_task(self._guard(record), name=f"task-{record.spec.name}")

    async def _guard(self, record: _TaskRecord) -> None:
        name = record.spec.name
        try:
            await record.spec.factory(lambda: self.beat(name))
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.exception("task %s failed", name)
            if record.task is asyncio.current_task():  # not a task already given up for a missed watchdog
                self._failed(record, f"{type(exc).__name__}: {exc}")
            return
        if record.task is asyncio.current_task():
            self._ended(record)

    def _ended(self, record: _TaskRecord) -> None:
        if record.spec.restart == "always":
            record.last_error = "returned; restarting (restart=always)"
            self._schedule_restart(record)
        else:
            record.state = "done"

    def _failed(self, record: _TaskRecord, why: str) -> None:
        record.last_error = why
        if record.spec.restart == "never":
            record.state = "failed"
            return
        self._schedule_restart(record)

    def _schedule_restart(self, record: _TaskRecord) -> None:
        now = self._clock()
        if now - record.started_t >= STABLE_AFTER_S:
            record.backoff.reset()
        record.state, record.restart_at = "backoff", now + record.backoff.next_s()

    # ----- the supervisor loop --------------------------------------------------------------------
    async def run(self, stop: asyncio.Event) -> None:
        """Supervise until `stop` is set: restarts, watchdog deadlines, systemd notifications."""
        interval = watchdog_interval_s()
        ping_every = interval / 2 if interval else None
        last_ping = -math.inf
        expected = self._clock() + self.tick_s
        while not stop.is_set():
            with contextlib.suppress(TimeoutError):  # not wait_for: on 3.11 it can swallow a cancel
                async with asyncio.timeout(self.tick_s):
                    await stop.wait()
            now = self._clock()
            self.loop_lag_s = max(0.0, now - expected)
            expected = now + self.tick_s
            self._credit_frozen_time(self.loop_lag_s)
            self.check(now)
            # READY=1 once the robot's own tasks run: a non-critical one (web console, worker watch) in
            # backoff is reported in STATUS= and retried, but must not keep systemd's start pending
            if not self.ready and all(r.state == "running" for r in self._records.values() if r.spec.critical):
                self.ready = True
                self.notifier.ready(self.status_line())
            if self.healthy and ping_every is not None and now - last_ping >= ping_every:
                self.notifier.watchdog()
                last_ping = now
            text = self.status_line()
            if text != self._last_status:
                self.notifier.status(text)
                self._last_status = text

    def _credit_frozen_time(self, lag_s: float) -> None:
        """A late tick means the whole loop was stalled (CPU starvation, a blocking call): that time is
        nobody's missed heartbeat, so it is added to every deadline; a task waiting forever at an await
        still misses its deadline, because the loop then runs on time."""
        if lag_s > 0.0:
            for record in self._records.values():
                record.last_beat_t += lag_s

    def check(self, now: float) -> None:
        """One supervision step: expire hung tasks, restart those whose backoff is over, judge health."""
        for task in list(self._cancelling):  # cancelled tasks: again each tick until they end (3.11 wait_for)
            if task.done():
                self._cancelling.discard(task)
            else:
                task.cancel()
        for record in self._records.values():
            deadline = record.spec.watchdog_s
            if record.state == "running" and deadline is not None and now - record.last_beat_t > deadline:
                log.error("task %s missed its %.2f s watchdog; restarting it", record.spec.name, deadline)
                if record.task is not None:
                    record.task.cancel()
                    self._cancelling.add(record.task)
                self._failed(record, f"no heartbeat for {now - record.last_beat_t:.2f} s (watchdog {deadline} s)")
            if record.state == "backoff" and now >= record.restart_at:
                record.restarts += 1
                log.warning("restarting task %s (restart %d)", record.spec.name, record.restarts)
                self._launch(record)
        down = [r for r in self._records.values() if r.spec.critical and r.state == "failed"]
        self.healthy = self.loop_lag_s < self._max_lag_s and not down

    def status_line(self) -> str:
        """The STATUS= text: task counts, then the robot's own summary."""
        records = self._records.values()
        running = sum(r.state == "running" for r in records)
        text = f"{running}/{len(records)} tasks running"
        troubled = [f"{r.spec.name} {r.state}" for r in records if r.state in ("backoff", "failed")]
        if troubled:
            text += " (" + ", ".join(troubled) + ")"
        if self._status_text is not None:
            text += "; " + self._status_text()
        return text

    async def stop(self) -> None:
        """Cancel every task, in reverse table order, and wait for them."""
        for record in reversed(list(self._records.values())):
            record.restart_at = math.inf
            task = record.task
            if task is not None and not task.done():
                began = self._clock()
                while not task.done():  # again and again: on 3.11 a wait_for inside a task can swallow one cancel
                    task.cancel()
                    await asyncio.wait({task}, timeout=0.1)
                if not task.cancelled() and task.exception() is not None:
                    log.debug("task %s ended with %r while stopping", record.spec.name, task.exception())
                log.debug("task %s stopped in %.3f s", record.spec.name, self._clock() - began)
            if record.state in ("running", "backoff"):
                record.state = "stopped"
