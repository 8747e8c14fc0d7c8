"""The web console's cost: its CPU while a survey streams to one browser, and the shell's e-stop with
three browsers connected against none.

The daemon runs on the simulated robot in this process (emulators on the same loop, as in
bench_daemon: pessimistic). Headless Chromium (Debian's chromium + chromium-driver) opens the console.
Console CPU is measured two ways: (1) the thread CPU time spent inside the console's own work — each
push (`WebConsole.tick`: new traces decimated, lines, status, JSON) and each WebSocket send — over the
survey's wall time; (2) the whole process's CPU during the same survey with the console streaming to a
browser, minus a survey with the console disabled (noisy on a loaded machine: a cross-check).
The shell's e-stop: jog → `estop` over a TCP shell connection → reply; the time from sending the line
to every emulated wheel commanded to zero, and to the reply, `--estops` times per case.
Three consoles are measured twice: as socket clients in another process (what the daemon serves to three
browsers on tablets, the robot's case) and as three headless Chromiums on this same machine (whose
rendering competes with the daemon for the two cores: pessimistic, not the robot's case).
Run: `.venv/bin/python -m benchmarks.bench_web [--lines 3 --length 0.6 --speed 0.1 --estops 60]`.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import functools
import multiprocessing
import tempfile
import time
from collections.abc import Awaitable, Callable
from typing import Any

import numpy as np

from benchmarks.machine import machine_description
from gprbot.config import Config, load_config
from gprbot.daemon import serve
from gprbot.robot.runtime import RobotRuntime
from gprbot.sdnotify import SdNotifier
from gprbot.web import server as web_server
from tests.web_support import browser_missing, chromium


class CpuMeter:
    """Thread CPU seconds spent inside the wrapped calls (the event loop's thread)."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self.calls = 0

    def wrap_sync(self, fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def timed(*args: Any, **kwargs: Any) -> Any:
            began = time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds += time.thread_time() - began
                self.calls += 1
        return timed

    def wrap_async(self, fn: Callable[..., Awaitable[Any]]) -> Callable[..., Awaitable[Any]]:
        @functools.wraps(fn)
        async def timed(*args: Any, **kwargs: Any) -> Any:
            began = time.thread_time()  # a send that has to wait for the socket also counts what runs meanwhile
            try:
                return await fn(*args, **kwargs)
            finally:
                self.seconds += time.thread_time() - began
                self.calls += 1
        return timed


def bench_config(runs: str, lines: int, length_m: float, speed_m_s: float, web: bool) -> Config:
    cfg = load_config()
    survey = dataclasses.replace(cfg.survey, lines=lines, length_m=length_m, speed_m_s=speed_m_s, start_xy_m=(0.1, 0.2))
    return dataclasses.replace(cfg, survey=survey, gpr=dataclasses.replace(cfg.gpr, eps_r=6.25), runs_dir=runs,
                               web=dataclasses.replace(cfg.web, enabled=web, port=0))


async def start_daemon(cfg: Config) -> tuple[RobotRuntime, asyncio.Event, asyncio.Task[int]]:
    stop = asyncio.Event()
    started: list[RobotRuntime] = []
    task = asyncio.create_task(serve(cfg, shell_port=0, stop=stop, use_worker=True, notifier=SdNotifier(environ={}),
                                     on_ready=started.append))  # type: ignore[arg-type]
    while not started or started[0].shell is None or (cfg.web.enabled and started[0].web is None):
        if task.done():
            raise RuntimeError(f"the daemon exited with {task.result()}")
        await asyncio.sleep(0.05)
    await asyncio.sleep(1.5)  # the filter's at-rest initialisation
    return started[0], stop, task


async def open_browsers(rt: RobotRuntime, count: int) -> list[Any]:
    """`count` headless Chromiums on the console, each with its live socket up."""
    browsers = []
    assert rt.web is not None
    url = f"http://127.0.0.1:{rt.web.port}/"
    for _ in range(count):
        browser = await asyncio.to_thread(chromium, 1400, 1000)
        await asyncio.to_thread(browser.get, url)
        browsers.append(browser)
    while rt.web.browser_count < count:
        await asyncio.sleep(0.05)
    return browsers


async def survey_cpu(cfg: Config, browsers: int) -> tuple[float, float, float, CpuMeter, str]:
    """Drive one survey; (wall s, process CPU s, console CPU s, meter, state)."""
    meter = CpuMeter()
    original_tick = web_server.WebConsole.tick
    web_server.WebConsole.tick = meter.wrap_sync(original_tick)  # type: ignore[method-assign]
    rt, stop, task = await start_daemon(cfg)
    opened = await open_browsers(rt, browsers) if browsers else []
    if rt.web is not None:  # count every WebSocket send of the console's sender tasks
        for browser in list(rt.web.browsers):
            browser.ws.send_str = meter.wrap_async(browser.ws.send_str)  # type: ignore[method-assign,assignment]
    await asyncio.sleep(1.0)
    meter.seconds, meter.calls = 0.0, 0
    run = rt.survey.start(cfg.survey)
    wall0, cpu0 = time.monotonic(), time.process_time()
    while run.state in ("starting", "running", "paused"):
        await asyncio.sleep(0.05)
    wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
    console_s = meter.seconds
    while run.state == "finishing":
        await asyncio.sleep(0.05)
    for browser in opened:
        await asyncio.to_thread(browser.quit)
    stop.set()
    await task
    web_server.WebConsole.tick = original_tick  # type: ignore[method-assign]
    return wall, cpu, console_s, meter, run.state


def socket_clients(url: str, count: int, stop: Any) -> None:
    """In another process: `count` console clients (cookie, then the live socket) reading until `stop` is set."""
    import aiohttp

    async def one() -> None:
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as http:
            async with http.get(url) as page:
                await page.text()
            async with http.ws_connect(url + "ws", origin=url.rstrip("/")) as ws:
                while not stop.is_set():
                    with contextlib.suppress(TimeoutError):
                        await ws.receive(timeout=0.5)

    async def main() -> None:
        await asyncio.gather(*(one() for _ in range(count)))

    asyncio.run(main())


class ShellEstops:
    """jog → `estop` → reset over one TCP shell connection; per e-stop, the time from sending the line to
    every emulated wheel commanded to zero and to the reply."""

    def __init__(self, rt: RobotRuntime, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.rt, self.reader, self.writer = rt, reader, writer
        self.wheels = set(rt.cfg.motors.wheel_map)

    async def ask(self, line: str) -> str:
        self.writer.write(line.encode() + b"\n")
        await self.writer.drain()
        while True:
            text = (await self.reader.readline()).decode()
            if text.startswith(("ok", "error")):
                return text

    async def once(self) -> tuple[float | None, float]:
        assert self.rt.sim is not None
        await self.ask("reset")
        await self.ask("jog 0.1 0 2")
        await asyncio.sleep(0.3)
        sent = time.monotonic()
        reply = await self.ask("estop")
        replied = time.monotonic()
        assert reply.startswith("ok estop"), reply
        zero: dict[tuple[int, int], float] = {}
        for event in list(self.rt.sim.motors.command_log):
            if event.t >= sent and event.counts_per_s == 0 and (event.address, event.channel) in self.wheels:
                zero.setdefault((event.address, event.channel), event.t)
        return (max(zero.values()) - sent if len(zero) == len(self.wheels) else None), replied - sent


async def open_consoles(rt: RobotRuntime, kind: str, count: int) -> Callable[[], Awaitable[None]]:
    """Open `count` consoles of `kind` ("sockets": clients in another process; "chromium"); their closer."""
    assert rt.web is not None
    if kind == "chromium":
        browsers = await open_browsers(rt, count)

        async def close_browsers() -> None:
            for browser in browsers:
                await asyncio.to_thread(browser.quit)
        return close_browsers
    context = multiprocessing.get_context("spawn")
    stop_clients = context.Event()
    clients = context.Process(target=socket_clients, args=(rt.web.url, count, stop_clients))
    clients.start()
    while rt.web.browser_count < count:
        await asyncio.sleep(0.05)

    async def close_clients() -> None:
        stop_clients.set()
        await asyncio.to_thread(clients.join, 10)
    return close_clients


async def estops_by_case(cfg: Config, rounds: int, per_round: int) -> dict[str, tuple[list[float], list[float]]]:
    """The three cases interleaved round by round on one daemon, so that the machine's load drifts alike."""
    cases = (("no console open", "", 0), ("3 consoles (socket clients in another process)", "sockets", 3),
             ("3 headless Chromiums on this same machine", "chromium", 3))
    rt, stop, task = await start_daemon(dataclasses.replace(cfg, web=dataclasses.replace(cfg.web, enabled=True)))
    shell = ShellEstops(rt, *await asyncio.open_connection("127.0.0.1", rt.shell_port))
    out: dict[str, tuple[list[float], list[float]]] = {name: ([], []) for name, _, _ in cases}
    for _ in range(rounds):
        for name, kind, count in cases:
            close = await open_consoles(rt, kind, count) if count else None
            await asyncio.sleep(1.0)  # the consoles settle into streaming
            for _ in range(per_round):
                wheels, reply = await shell.once()
                if wheels is not None:
                    out[name][0].append(wheels)
                out[name][1].append(reply)
            if close is not None:
                await close()
                while rt.web is not None and rt.web.browser_count:
                    await asyncio.sleep(0.05)
    shell.writer.close()
    stop.set()
    await task
    return out


def ms(values: list[float]) -> str:
    a = np.array(values) * 1000
    return (f"median {np.median(a):6.2f} ms  p99 {np.percentile(a, 99):7.2f} ms  max {a.max():7.1f} ms  (n={a.size})"
            if a.size else "no samples")


async def print_survey_cpu(runs: str, lines: int, length_m: float, speed_m_s: float) -> None:
    """The console's CPU while a survey streams to one browser (and the whole process's, with and without)."""
    streamed = bench_config(runs, lines, length_m, speed_m_s, True)
    wall1, cpu1, console_s, meter, state1 = await survey_cpu(streamed, 1)
    wall0, cpu0, _, _, state0 = await survey_cpu(bench_config(runs, lines, length_m, speed_m_s, False), 0)
    print(f"survey {lines} lines x {length_m} m at {speed_m_s} m/s ({state1}, {state0}):")
    print(f"  console's own work with one browser: {console_s:.3f} s CPU over {wall1:.1f} s = "
          f"{100 * console_s / wall1:.2f} % of one core ({meter.calls} pushes and sends)")
    print(f"  whole process: {100 * cpu1 / wall1:.1f} % of a core with the console streaming to a browser, "
          f"{100 * cpu0 / wall0:.1f} % with the console disabled: difference "
          f"{100 * (cpu1 / wall1 - cpu0 / wall0):+.1f} % (includes noise of a loaded machine)")


async def bench(lines: int, length_m: float, speed_m_s: float, estops: int, cpu: bool = True) -> None:
    missing = browser_missing()
    if missing:
        print(f"bench_web skipped: {missing}")
        return
    with tempfile.TemporaryDirectory() as runs:
        print(f"machine: {machine_description()}")
        streamed = bench_config(runs, lines, length_m, speed_m_s, True)
        if cpu:
            await print_survey_cpu(runs, lines, length_m, speed_m_s)
        rounds = max(1, estops // 10)
        for what, (wheels, replies) in (await estops_by_case(streamed, rounds, 10)).items():
            print(f"shell e-stop, {what} ({rounds} rounds of 10, interleaved with the other cases):\n"
                  f"  to wheels {ms(wheels)}\n  to reply  {ms(replies)}")
        print("(p99 of a few dozen samples is about their worst one or two: read it with the max)")


def main() -> None:
    """Parse the arguments and run the benchmark."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--lines", type=int, default=3)
    parser.add_argument("--length", type=float, default=0.6)
    parser.add_argument("--speed", type=float, default=0.1)
    parser.add_argument("--estops", type=int, default=60)
    parser.add_argument("--no-cpu", action="store_true", help="only the e-stop figures")
    args = parser.parse_args()
    asyncio.run(bench(args.lines, args.length, args.speed, args.estops, cpu=not args.no_cpu))


if __name__ == "__main__":
    main()
