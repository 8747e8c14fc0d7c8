"""Helpers for the web console's tests: the daemon on the simulated robot in a thread, headless Chromium."""

from __future__ import annotations

import asyncio
import dataclasses
import os
import shutil
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gprbot.config import Config, load_config
from gprbot.daemon import serve
from gprbot.drivers.motors.emulator import MotorCommandEvent
from gprbot.robot.runtime import RobotRuntime
from gprbot.sdnotify import SdNotifier

REPO = Path(__file__).resolve().parents[1]
ARTIFACTS = Path(os.environ.get("GPRBOT_TEST_ARTIFACTS", REPO / "test-artifacts")) / "web"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")


def browser_missing() -> str | None:
    """Why the browser tests cannot run here (None when they can)."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install -e '.[dev]')"
    if CHROMIUM is None or CHROMEDRIVER is None:
        return ("headless Chromium is absent: apt-get install chromium chromium-driver "
                "(scripts/bootstrap.sh does, as root)")
    return None


def web_config(tmp_path: Path, **survey: Any) -> Config:
    """The sim config with short lines across the paper slab's steel pipe, web and shell on free ports."""
    cfg = load_config()
    lines = dataclasses.replace(cfg.survey, **{"lines": 2, "length_m": 0.6, "speed_m_s": 0.2, "settle_s": 0.3,
                                                "start_xy_m": (0.1, 0.2), **survey})
    return dataclasses.replace(cfg, survey=lines, gpr=dataclasses.replace(cfg.gpr, eps_r=6.25),
                               web=dataclasses.replace(cfg.web, port=0), runs_dir=str(tmp_path / "runs"))


class DaemonThread:
    """`gprbot run` on the simulated robot in a background thread, with its own event loop."""

    def __init__(self, cfg: Config, *, token_file: str | None = None, use_worker: bool = False) -> None:
        self.cfg, self.token_file, self.use_worker = cfg, token_file, use_worker
        self.runtime: RobotRuntime | None = None
        self.exit_status: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._main, name="gprbot-daemon", daemon=True)

    def _main(self) -> None:
        async def main() -> int:
            self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
            return await serve(self.cfg, shell_port=0, token_file=self.token_file, stop=self._stop,
                               use_worker=self.use_worker, notifier=SdNotifier(environ={}), on_ready=self._on_ready)

        try:
            self.exit_status = asyncio.run(main())
        finally:
            self._ready.set()

    def _on_ready(self, runtime: object) -> None:
        assert isinstance(runtime, RobotRuntime)
        self.runtime = runtime

    def start(self, timeout_s: float = 60.0) -> DaemonThread:
        """Start and wait until the shell and the web console listen."""
        self._thread.start()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            rt = self.runtime
            if rt is not None and rt.shell is not None and rt.web is not None:
                return self
            if self.exit_status is not None:
                raise RuntimeError(f"the daemon exited with {self.exit_status}")
            time.sleep(0.05)
        raise TimeoutError("the daemon did not start its web console")

    @property
    def url(self) -> str:
        """The console's address."""
        assert self.runtime is not None and self.runtime.web is not None
        return f"http://127.0.0.1:{self.runtime.web.port}/"

    def call(self, fn: Callable[[], Any]) -> Any:
        """Run fn on the daemon's loop and return its result (for reading state consistently)."""
        assert self._loop is not None
        done = threading.Event()
        box: list[Any] = []

        def run() -> None:
            box.append(fn())
            done.set()

        self._loop.call_soon_threadsafe(run)
        assert done.wait(10.0), "the daemon's loop did not answer"
        return box[0]

    def motor_commands(self) -> list[MotorCommandEvent]:
        """Every speed command the emulated RoboClaws received so far."""
        assert self.runtime is not None and self.runtime.sim is not None
        motors = self.runtime.sim.motors
        return list(self.call(lambda: list(motors.command_log)))

    def stop(self) -> None:
        """SIGTERM-like stop, waiting for the daemon to exit."""
        if self._loop is not None and self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(60.0)


def chromium(width: int = 1600, height: int = 1100) -> Any:
    """Headless Chromium driven by chromedriver (Debian's packages)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM or ""
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", f"--window-size={width},{height}",
                "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-gpu-sandbox"):
        options.add_argument(arg)
    return webdriver.Chrome(service=Service(CHROMEDRIVER or ""), options=options)


def _navigating(exc: Exception) -> bool:
    """Whether a WebDriver error only says the page was replaced under the element being read."""
    if type(exc).__name__ in ("NoSuchElementException", "StaleElementReferenceException"):
        return True
    # Chromium 156 reports a node swapped out by a form post as an "unknown error" rather than a stale element.
    return type(exc).__name__ == "WebDriverException" and "does not belong to the document" in str(exc)


def wait_for(check: Callable[[], Any], timeout_s: float, what: str, poll_s: float = 0.1) -> Any:
    """Poll `check` until it returns something truthy; its value (AssertionError naming `what` on timeout)."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            value = check()
        except Exception as exc:  # the page is navigating: an element not there yet, or gone stale
            if not _navigating(exc):
                raise
            value = None
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(poll_s)
