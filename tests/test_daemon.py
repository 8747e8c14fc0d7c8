"""The daemon: supervisor restarts and watchdogs, sd_notify over a real socket, and the whole robot on
the simulated world driven through its own TCP shell — survey → run directory, e-stop latency,
SIGTERM mid-survey."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import os
import signal
import socket
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData

from gprbot.config import Config, load_config
from gprbot.daemon import serve
from gprbot.messages import SurveyEvent
from gprbot.robot.runtime import RobotRuntime
from gprbot.runlog_reader import RunLogReader
from gprbot.sdnotify import SdNotifier, watchdog_interval_s
from gprbot.shell.protocol import ReplyReader, ServerEvent, ServerReply
from gprbot.supervisor import Supervisor, TaskSpec


# ----- sd_notify ------------------------------------------------------------------------------------
@pytest.fixture
def notify_socket(tmp_path: Path) -> socket.socket:
    """A datagram socket standing in for systemd's notify socket."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "notify"))
    sock.settimeout(2.0)
    yield sock
    sock.close()


def received(sock: socket.socket) -> list[str]:
    """Every datagram waiting on the socket."""
    out = []
    sock.setblocking(False)
    try:
        while True:
            out.append(sock.recv(4096).decode())
    except BlockingIOError:
        return out
    finally:
        sock.setblocking(True)


def test_sdnotify_sends_datagrams_and_is_silent_without_systemd(notify_socket: socket.socket) -> None:
    notifier = SdNotifier(notify_socket.getsockname())
    assert notifier.ready("up") and notifier.watchdog() and notifier.stopping()
    assert received(notify_socket) == ["READY=1\nSTATUS=up", "WATCHDOG=1", "STOPPING=1"]
    notifier.close()
    silent = SdNotifier(environ={})
    assert not silent.enabled and not silent.ready()


def test_watchdog_interval_follows_systemd_environment() -> None:
    assert watchdog_interval_s({"WATCHDOG_USEC": "3000000"}) == 3.0
    assert watchdog_interval_s({"WATCHDOG_USEC": "3000000", "WATCHDOG_PID": str(os.getpid() + 1)}) is None
    assert watchdog_interval_s({}) is None


# ----- the supervisor -------------------------------------------------------------------------------
async def test_ready_is_not_held_back_by_a_failing_non_critical_task(notify_socket: socket.socket) -> None:
    async def steady(beat: Callable[[], None]) -> None:
        while True:
            beat()
            await asyncio.sleep(0.01)

    async def broken(beat: Callable[[], None]) -> None:
        raise OSError("port 8780 in use")

    notifier = SdNotifier(notify_socket.getsockname())
    supervisor = Supervisor([TaskSpec("motion", steady, watchdog_s=0.5),
                             TaskSpec("web", broken, watchdog_s=0.5, critical=False)],
                            notifier, tick_s=0.02, backoff_s=(0.05, 1.0))
    stop = asyncio.Event()
    supervisor.start()
    runner = asyncio.create_task(supervisor.run(stop))
    await asyncio.sleep(0.3)
    stop.set()
    await runner
    await supervisor.stop()
    notifier.close()
    messages = received(notify_socket)
    ready = [i for i, m in enumerate(messages) if m.startswith("READY=1")]
    backoff = [i for i, m in enumerate(messages) if m.startswith("STATUS=") and "web backoff" in m]
    assert len(ready) == 1 and backoff
    assert ready[0] < backoff[0]  # at once: before, READY=1 waited until the web task happened to be relaunched
    assert {h.name: h for h in supervisor.health()}["web"].restarts >= 1


async def test_supervisor_restarts_a_crashing_task_with_backoff_and_notifies(
        notify_socket: socket.socket, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("WATCHDOG_USEC", "200000")
    runs: list[float] = []
    loop = asyncio.get_running_loop()

    async def crashes_twice(beat: Callable[[], None]) -> None:
        runs.append(loop.time())
        if len(runs) <= 2:
            raise RuntimeError(f"crash {len(runs)}")
        while True:
            beat()
            await asyncio.sleep(0.01)

    async def steady(beat: Callable[[], None]) -> None:
        while True:
            beat()
            await asyncio.sleep(0.01)

    notifier = SdNotifier(notify_socket.getsockname())
    supervisor = Supervisor([TaskSpec("flaky", crashes_twice, watchdog_s=0.5, restart="always"),
                             TaskSpec("steady", steady, watchdog_s=0.5)],
                            notifier, tick_s=0.02, backoff_s=(0.05, 1.0))
    stop = asyncio.Event()
    supervisor.start()
    runner = asyncio.create_task(supervisor.run(stop))
    while len(runs) < 3:
        await asyncio.sleep(0.01)
    await asyncio.sleep(0.1)
    stop.set()
    await runner
    health = {h.name: h for h in supervisor.health()}
    assert health["flaky"].state == "running" and health["flaky"].restarts == 2
    assert health["flaky"].last_error == "RuntimeError: crash 2"
    assert health["steady"].restarts == 0
    gaps = np.diff(runs)
    assert gaps[0] >= 0.05 and gaps[1] >= 0.1  # exponential backoff: 0.05 s, then 0.1 s
    await supervisor.stop()
    notifier.close()
    messages = received(notify_socket)
    assert sum(m.startswith("READY=1") for m in messages) == 1
    assert "WATCHDOG=1" in messages
    assert any("flaky backoff" in m for m in messages if m.startswith("STATUS="))


async def test_supervisor_restarts_a_task_that_stops_beating() -> None:
    starts = 0

    async def hangs_once(beat: Callable[[], None]) -> None:
        nonlocal starts
        starts += 1
        beat()
        if starts == 1:
            await asyncio.Event().wait()  # stuck at an await: the loop runs on, the beats stop
        while True:
            beat()
            await asyncio.sleep(0.01)

    supervisor = Supervisor([TaskSpec("hangs", hangs_once, watchdog_s=0.1)], SdNotifier(environ={}),
                            tick_s=0.02, backoff_s=(0.01, 0.1))
    stop = asyncio.Event()
    supervisor.start()
    runner = asyncio.create_task(supervisor.run(stop))
    while starts < 2:
        await asyncio.sleep(0.01)
    stop.set()
    await runner
    (health,) = supervisor.health()
    assert health.restarts == 1 and "no heartbeat" in (health.last_error or "")
    await supervisor.stop()


# ----- the daemon on the simulated robot ------------------------------------------------------------
def sim_config(tmp_path: Path) -> Config:
    """Three 0.6 m lines at 0.2 m/s across the paper slab's steel pipe at x = 0.35 m (known eps_r)."""
    cfg = load_config()
    survey = dataclasses.replace(cfg.survey, lines=3, length_m=0.6, speed_m_s=0.2, settle_s=0.3, start_xy_m=(0.1, 0.2))
    return dataclasses.replace(cfg, survey=survey, gpr=dataclasses.replace(cfg.gpr, eps_r=6.25),
                               runs_dir=str(tmp_path / "runs"))


class ShellClient:
    """A minimal client of the daemon's TCP shell: one command, its reply; events are collected."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer
        self.parser = ReplyReader()
        self.events: list[str] = []
        self._replies: list[ServerReply] = []

    async def command(self, line: str, timeout_s: float = 10.0) -> ServerReply:
        self.writer.write(line.encode() + b"\n")
        await self.writer.drain()
        async with asyncio.timeout(timeout_s):
            while not self._replies:
                await self._read()
        return self._replies.pop(0)

    async def wait_event(self, prefix: str, timeout_s: float) -> str:
        async with asyncio.timeout(timeout_s):
            while True:
                for event in self.events:
                    if event.startswith(prefix):
                        return event
                await self._read()

    async def _read(self) -> None:
        data = await self.reader.read(65536)
        assert data, "the daemon closed the shell connection"
        for item in self.parser.feed(data):
            if isinstance(item, ServerEvent):
                self.events.append(item.text)
            elif isinstance(item, ServerReply):
                self._replies.append(item)


Daemon = tuple[RobotRuntime, ShellClient, "asyncio.Task[int]", asyncio.Event]


@contextlib.asynccontextmanager
async def running_daemon(tmp_path: Path, use_worker: bool, notifier: SdNotifier | None = None) -> AsyncIterator[Daemon]:
    """The daemon on the sim config with its shell on an ephemeral port, and a connected client."""
    stop = asyncio.Event()
    started: list[RobotRuntime] = []
    task = asyncio.create_task(serve(sim_config(tmp_path), shell_port=0, stop=stop, use_worker=use_worker,
                                     notifier=notifier or SdNotifier(environ={}),
                                     on_ready=started.append))  # type: ignore[arg-type]
    async with asyncio.timeout(30):
        while not started or started[0].shell is None:
            assert not task.done(), f"the daemon exited with {task.result()}"
            await asyncio.sleep(0.02)
    runtime = started[0]
    client = ShellClient(*await asyncio.open_connection("127.0.0.1", runtime.shell_port))
    try:
        yield runtime, client, task, stop
    finally:
        client.writer.close()
        stop.set()
        async with asyncio.timeout(30):
            await task


@pytest.fixture
async def daemon(tmp_path: Path) -> AsyncIterator[Daemon]:
    """The daemon with its inference worker process."""
    async with running_daemon(tmp_path, use_worker=True) as running:
        yield running


@pytest.fixture
async def daemon_no_worker(tmp_path: Path, notify_socket: socket.socket) -> AsyncIterator[Daemon]:
    """The daemon reconstructing in a thread (the worker process costs seconds to start), telling
    `notify_socket` what it would tell systemd."""
    notifier = SdNotifier(notify_socket.getsockname())
    async with running_daemon(tmp_path, use_worker=False, notifier=notifier) as running:
        yield running


async def test_survey_through_the_shell_writes_a_run_directory(daemon: Daemon) -> None:
    runtime, client, _, _ = daemon
    status = await client.command("status")
    assert status.ok and "mode idle" in status.body
    assert any(line.startswith("task motion running") for line in status.body)
    reply = await client.command("survey start")
    assert reply.ok, reply
    run_name = reply.text.split()[1]
    assert (await client.command("jog 0.1 0 1")).code == "busy"
    done = await client.wait_event("survey done", timeout_s=45)
    assert done == f"survey done {run_name} pipes {runtime.survey.current.pipes}"
    run_dir = Path(runtime.cfg.runs_dir) / run_name
    for name in ("sparse.ply", "dense.ply", "pipes.json", "summary.json", "log-000.msgpack"):
        assert (run_dir / name).stat().st_size > 0, name
    # The scene's steel pipe runs along y at x = 0.35 m, axis 0.12 m deep, radius 0.03 m: the slices that
    # the traces and the fused poses register in 3D must lie on it, on more than one survey line.
    vertex = PlyData.read(str(run_dir / "sparse.ply"))["vertex"]
    x, y, z = (np.asarray(vertex[k]) for k in ("x", "y", "z"))
    on_pipe = (np.abs(x - 0.35) < 0.05) & (z > -0.18) & (z < -0.06)
    assert on_pipe.mean() > 0.9, np.percentile(np.c_[x, y, z], [5, 50, 95], axis=0)
    assert len(set(np.round(y[on_pipe], 1))) >= 2
    planned_y = 0.2 + 0.1 * np.arange(3)  # plan tracking keeps the lines on their planned spacing
    assert np.all(np.min(np.abs(y[:, None] - planned_y[None, :]), axis=1) < 0.025)
    pipes = json.loads((run_dir / "pipes.json").read_text())["pipes"]
    assert all(abs(point[0] - 0.35) < 0.05 for pipe in pipes for point in pipe["axis_m"]), pipes
    log = RunLogReader(run_dir)
    events = [r.message for r in log if isinstance(r.message, SurveyEvent)]
    assert [e.kind for e in events if e.kind == "line_start"] == ["line_start"] * 3
    assert log.ended


async def test_estop_stops_every_wheel_within_100_ms_and_latches(daemon_no_worker: Daemon) -> None:
    runtime, client, _, _ = daemon_no_worker
    emulator = runtime.sim.motors
    wheel_map = runtime.cfg.motors.wheel_map
    assert (await client.command("jog 0.2 0 5")).ok
    async with asyncio.timeout(5):
        while min(abs(emulator.commanded_speed(a, c)) for a, c in wheel_map) < 1.0:
            await asyncio.sleep(0.01)
    arrivals: list[float] = []
    original = runtime.estop

    async def timed_estop() -> float:
        arrivals.append(runtime.clock())
        return await original()

    runtime.estop = timed_estop  # type: ignore[method-assign]
    reply = await client.command("estop")
    assert reply.ok and "latched" in reply.text
    arrived = arrivals[0]
    stopped_at = []
    for address, channel in wheel_map:
        zeros = [e.t for e in emulator.command_log
                 if e.t >= arrived and (e.address, e.channel) == (address, channel) and e.counts_per_s == 0]
        assert zeros, f"wheel {address}/{channel} was never commanded to 0"
        stopped_at.append(zeros[0])
    latency_s = max(stopped_at) - arrived
    print(f"estop latency: {latency_s * 1000:.2f} ms")
    assert 0 <= latency_s <= 0.1
    await asyncio.sleep(0.2)  # the motion loop must not command the wheels again while latched
    assert all(emulator.commanded_speed(a, c) == 0 for a, c in wheel_map)
    assert (await client.command("jog 0.1 0 1")).code == "estopped"
    assert (await client.command("survey start")).code == "estopped"
    assert "estop latched" in (await client.command("status")).body
    assert (await client.command("reset")).ok
    # The jog deadman: a jog whose session goes quiet ends after motion.jog_deadman_timeout_s.
    assert (await client.command("jog 0.2 0 10")).ok
    loop = asyncio.get_running_loop()
    began = loop.time()
    async with asyncio.timeout(5):
        while min(abs(emulator.commanded_speed(a, c)) for a, c in wheel_map) < 1.0:
            await asyncio.sleep(0.01)
        while any(emulator.commanded_speed(a, c) != 0 for a, c in wheel_map):
            await asyncio.sleep(0.01)
    quiet_for = loop.time() - began
    assert runtime.cfg.motion.jog_deadman_timeout_s <= quiet_for < runtime.cfg.motion.jog_deadman_timeout_s + 0.5


async def test_sigterm_mid_survey_stops_wheels_and_closes_the_run_log(daemon_no_worker: Daemon) -> None:
    runtime, client, task, _ = daemon_no_worker
    assert (await client.command("survey start lines=2")).ok
    await client.wait_event("line 0 start", timeout_s=10)
    emulator = runtime.sim.motors
    wheel_map = runtime.cfg.motors.wheel_map
    assert (await client.command("survey pause")).ok
    # Poll rather than sleep a fixed time: a loaded CI machine may take longer than the motion loop's tick.
    async with asyncio.timeout(5):
        while any(emulator.commanded_speed(a, c) != 0 for a, c in wheel_map):
            await asyncio.sleep(0.01)
    assert any(" paused line 1/2 " in line for line in (await client.command("status")).body)
    assert (await client.command("survey resume")).ok
    async with asyncio.timeout(5):
        while min(abs(emulator.commanded_speed(a, c)) for a, c in wheel_map) <= 1.0:
            await asyncio.sleep(0.01)
    os.kill(os.getpid(), signal.SIGTERM)  # the daemon's own handler, as systemd stops it
    async with asyncio.timeout(20):
        assert await task == 0
    assert all(emulator.commanded_speed(a, c) == 0 for a, c in wheel_map)
    run = runtime.survey.current
    log = RunLogReader(run.run_dir)
    kinds = [r.message.kind for r in log if isinstance(r.message, SurveyEvent)]
    assert kinds[:2] == ["survey_start", "line_start"] and "line_end" in kinds and kinds[-1] == "abort"
    assert log.ended and log.summary is not None and log.summary["aborted"] == "shutdown"


async def test_the_daemon_tells_systemd_ready_status_and_stopping(
        daemon_no_worker: Daemon, notify_socket: socket.socket) -> None:
    _, client, task, stop = daemon_no_worker
    assert (await client.command("status")).ok
    messages: list[str] = []
    async with asyncio.timeout(5):
        while not any(m.startswith("READY=1") for m in messages):
            messages += received(notify_socket)
            await asyncio.sleep(0.05)
    ready = next(m for m in messages if m.startswith("READY=1"))
    assert "tasks running" in ready and "STATUS=" in ready
    stop.set()
    async with asyncio.timeout(20):
        assert await task == 0
    messages += received(notify_socket)
    assert messages[-1].startswith("STOPPING=1")
    assert not any(m.startswith("WATCHDOG") for m in messages)  # no WATCHDOG_USEC: no watchdog pings
