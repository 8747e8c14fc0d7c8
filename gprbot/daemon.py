"""The daemon: builds the robot runtime, hands its task table to the supervisor, runs until told to stop.

`run_daemon(cfg)` is `gprbot run`: it builds the robot (simulated by default), runs until SIGTERM or
SIGINT, then stops the wheels, ends the current line, closes the run log and the worker, and exits 0.
The daemon adds the operator-facing tasks it owns (the web console) to the runtime's table, so that the
robot runtime never imports its front ends.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import time
from collections.abc import Awaitable, Callable, Mapping

from gprbot.config import Config
from gprbot.errors import GprbotError
from gprbot.robot.runtime import RobotRuntime
from gprbot.sdnotify import SdNotifier
from gprbot.shutdown_budget import SHUTDOWN_STEPS_S
from gprbot.supervisor import Supervisor, TaskSpec
from gprbot.web.server import serve_console

log = logging.getLogger(__name__)


def frontend_tasks(runtime: RobotRuntime, token_file: str | None) -> list[TaskSpec]:
    """The operator-facing tasks the daemon adds to the runtime's table (the web console, when enabled)."""
    if not runtime.cfg.web.enabled:
        return []

    async def run_web(beat: Callable[[], None]) -> None:
        await serve_console(runtime, beat, token_file=token_file)

    return [TaskSpec("web", run_web, watchdog_s=5.0, restart="always", critical=False)]


# ----- gprbot run ---------------------------------------------------------------------------------
async def serve(cfg: Config, *, shell_host: str = "127.0.0.1", shell_port: int | None = None,
                token_file: str | None = None, stop: asyncio.Event | None = None,
                notifier: SdNotifier | None = None, use_worker: bool = True,
                on_ready: Callable[[RobotRuntime], None] | None = None) -> int:
    """Run the daemon on the running loop until `stop` (or SIGTERM/SIGINT); the exit status."""
    stop = stop or asyncio.Event()
    notifier = notifier or SdNotifier()
    loop = asyncio.get_running_loop()
    installed: list[signal.Signals] = []
    for signum in (signal.SIGTERM, signal.SIGINT):
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):  # not the main thread
            loop.add_signal_handler(signum, stop.set)
            installed.append(signum)
    runtime = RobotRuntime(cfg, shell_host=shell_host, shell_port=shell_port, token_file=token_file,
                           use_worker=use_worker)
    try:
        try:
            await runtime.start_devices()
        except GprbotError as exc:
            log.critical("cannot start: %s", exc)
            notifier.status(f"failed to start: {exc}")
            await runtime.close_devices()
            return 1
        supervisor = Supervisor(runtime.task_table(frontend_tasks(runtime, token_file)), notifier,
                                status_text=runtime.status_text)
        runtime.supervisor = supervisor
        supervisor.start()
        if on_ready is not None:
            on_ready(runtime)
        await supervisor.run(stop)
        notifier.stopping("stopping: wheels, current line, run log, worker")
        steps = SHUTDOWN_STEPS_S
        await _bounded("stop the wheels and end the run", runtime.shutdown(), steps["stop the wheels and end the run"])
        await _bounded("cancel the tasks", supervisor.stop(), steps["cancel the tasks"])
        await _bounded("close the devices and the worker", runtime.close_devices(),
                       steps["close the devices and the worker"])
        return 0
    finally:
        for signum in installed:
            loop.remove_signal_handler(signum)
        notifier.close()


async def _bounded(what: str, step: Awaitable[None], timeout_s: float) -> None:
    """One shutdown step, given at most timeout_s (systemd's stop timeout must not be the one to end us)."""
    began = time.monotonic()
    try:
        async with asyncio.timeout(timeout_s):
            await step
    except TimeoutError:
        log.error("shutdown: %s took over %.0f s; going on", what, timeout_s)
    else:
        log.info("shutdown: %s in %.2f s", what, time.monotonic() - began)


JOURNAL_PRIORITIES = {logging.CRITICAL: 2, logging.ERROR: 3, logging.WARNING: 4, logging.INFO: 6, logging.DEBUG: 7}


class JournalFormatter(logging.Formatter):
    """`<N>` syslog priority prefixes (sd-daemon(3)) so `journalctl -p err` finds the errors; one line per
    record (a traceback's lines are joined) so that the priority covers all of it."""

    def format(self, record: logging.LogRecord) -> str:
        """The record as `<priority>LEVEL name: message`."""
        level = max((lv for lv in JOURNAL_PRIORITIES if lv <= record.levelno), default=logging.DEBUG)
        text = super().format(record).replace("\n", " ⏎ ")
        return f"<{JOURNAL_PRIORITIES[level]}>{text}"


def configure_logging(environ: Mapping[str, str] | None = None) -> None:
    """Log to stderr; under systemd (JOURNAL_STREAM set), with journald priorities and without times."""
    root = logging.getLogger()
    if root.handlers:
        return
    env = os.environ if environ is None else environ
    handler = logging.StreamHandler()
    fmt = "%(levelname)s %(name)s: %(message)s"
    handler.setFormatter(JournalFormatter(fmt) if env.get("JOURNAL_STREAM") else logging.Formatter(fmt))
    root.addHandler(handler)
    root.setLevel(logging.INFO)


def run_daemon(cfg: Config, *, shell_host: str = "127.0.0.1", shell_port: int | None = None,
               token_file: str | None = None) -> int:
    """`gprbot run --config FILE`: run the robot daemon until SIGTERM/SIGINT; the process exit status."""
    configure_logging()
    return asyncio.run(serve(cfg, shell_host=shell_host, shell_port=shell_port, token_file=token_file))
