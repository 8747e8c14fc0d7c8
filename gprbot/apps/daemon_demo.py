"""`gprbot demo` (the default, through the daemon): the operator's path — start the daemon on the simulated
robot, drive it over its TCP shell (`survey start`, events, `files`, `pull`), pull the results,
stop it as systemd would."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from gprbot.config import Config
from gprbot.daemon import serve
from gprbot.errors import GprbotError
from gprbot.robot.runtime import RobotRuntime
from gprbot.shell.client import ShellConnection, pull_run


@dataclass(frozen=True)
class ShellDemoResult:
    """What the online demo produced: the run's name, the files pulled over the shell, the daemon's exit."""

    run: str
    pulled: tuple[Path, ...]
    exit_status: int


async def survey_via_shell(
    cfg: Config, dest: Path, *, timeout_s: float = 1800.0, on_event: Callable[[str], None] = lambda _: None,
    on_console: Callable[[str], None] = lambda _: None,
) -> ShellDemoResult:
    """Run the daemon on `cfg` (simulated), survey through its TCP shell, pull every result file into `dest`.

    `on_console` gets the web console's URL once it listens (before the survey starts), if it is enabled."""
    stop = asyncio.Event()
    started: list[RobotRuntime] = []
    daemon = asyncio.create_task(serve(cfg, shell_port=0, stop=stop, on_ready=started.append))
    done: asyncio.Future[str] = asyncio.get_running_loop().create_future()

    def event(text: str) -> None:
        on_event(text)
        if text.startswith(("survey done", "survey failed")) and not done.done():
            done.set_result(text)

    try:
        async with asyncio.timeout(timeout_s):
            while not started or started[0].shell is None:
                if daemon.done():
                    raise GprbotError(f"the daemon did not start (exit status {daemon.result()}); see the log")
                await asyncio.sleep(0.05)
            port = started[0].shell_port
            await _announce_console(started[0], on_console)
            async with ShellConnection("127.0.0.1", port, event) as shell:
                await shell.check("status")
                run = (await shell.check("survey start")).text.split()[1]
                outcome = await done
            if outcome.startswith("survey failed"):
                raise GprbotError(outcome)
            pulled = await pull_run("127.0.0.1", port, run, dest)
    finally:
        stop.set()
        status = await daemon
    return ShellDemoResult(run, tuple(pulled), status)


async def _announce_console(runtime: RobotRuntime, on_console: Callable[[str], None], wait_s: float = 5.0) -> None:
    """Tell the web console's URL once it listens (it starts beside the shell; a busy port only delays it)."""
    if not runtime.cfg.web.enabled:
        return
    for _ in range(int(wait_s / 0.05)):
        if runtime.web is not None:
            on_console(runtime.web.url)
            return
        await asyncio.sleep(0.05)
    on_console(f"(the web console is not up yet on port {runtime.cfg.web.port}; see the log)")
