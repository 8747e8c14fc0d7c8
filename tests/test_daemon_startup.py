"""Issue 15 #5 and #4: a shell config that leaves the robot unreachable fails the start (no READY=1, exit
non-zero, one line); an e-stop flood on the real daemon coalesces instead of starving the motor bus."""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from gprbot.daemon import serve
from gprbot.sdnotify import SdNotifier
from tests.test_daemon import ShellClient, notify_socket, received, running_daemon, sim_config  # noqa: F401


def _loose_token(tmp_path: Path) -> str:
    path = tmp_path / "token"
    path.write_text("a-token-of-enough-characters\n")
    path.chmod(0o644)
    return str(path)


@pytest.mark.parametrize("case", ["no token beyond loopback", "token file readable by others", "port in use"])
async def test_a_shell_that_cannot_serve_fails_the_start_without_ready(
        tmp_path: Path, notify_socket: socket.socket, case: str) -> None:  # noqa: F811
    cfg = sim_config(tmp_path)
    host, token, port = "127.0.0.1", None, 0
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    if case == "no token beyond loopback":
        host = "0.0.0.0"
    elif case == "token file readable by others":
        host, token = "0.0.0.0", _loose_token(tmp_path)
    else:
        port = busy.getsockname()[1]
    try:
        async with asyncio.timeout(20):
            status = await serve(cfg, shell_host=host, shell_port=port, token_file=token, use_worker=False,
                                 notifier=SdNotifier(notify_socket.getsockname()))
    finally:
        busy.close()
    assert status == 1
    messages = received(notify_socket)
    assert not any(m.startswith(("READY=1", "WATCHDOG=1")) for m in messages)
    assert any(m.startswith("STATUS=failed to start") for m in messages)


def test_gprbot_run_with_an_unreachable_shell_exits_non_zero_with_one_line(tmp_path: Path) -> None:
    config = tmp_path / "robot.yaml"
    config.write_text(f"shell: {{host: 0.0.0.0, port: 0}}\nsim: {{poses: noise}}\nruns_dir: {tmp_path / 'runs'}\n")
    done = subprocess.run([sys.executable, "-m", "gprbot.cli", "run", "--config", str(config)],
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode != 0
    output = done.stdout + done.stderr
    assert "Traceback" not in output
    assert [line for line in output.splitlines() if "without a token" in line] == [
        next(line for line in output.splitlines() if "cannot start" in line)]


async def test_an_estop_flood_coalesces_and_starves_no_task(tmp_path: Path) -> None:
    async with running_daemon(tmp_path, use_worker=False) as (runtime, client, _, _):
        assert (await client.command("status")).ok
        assert runtime.motors is not None
        stops = 0
        real_stop = runtime.motors.stop

        async def counting_stop() -> None:
            nonlocal stops
            stops += 1
            await real_stop()

        runtime.motors.stop = counting_stop  # type: ignore[method-assign]
        flood = await asyncio.open_connection("127.0.0.1", runtime.shell_port)
        loop = asyncio.get_running_loop()
        began = loop.time()
        for _ in range(20):  # 20 000 e-stops in about a second
            flood[1].write(b"estop\n" * 1000)
            await flood[1].drain()
            await asyncio.sleep(0.05)
        elapsed = loop.time() - began
        assert (await client.command("estop")).ok
        assert stops <= 2 + elapsed / 0.5  # one stop, then at most one per ESTOP_REPEAT_S
        assert runtime.supervisor is not None
        assert all(t.restarts == 0 for t in runtime.supervisor.health()), runtime.supervisor.health()
        flood[1].close()


@pytest.mark.timeout(240)
async def test_waiting_for_a_reconnect_or_a_failed_survey_is_not_a_task_crash(tmp_path: Path) -> None:
    """Soak findings: the encoder task missed its watchdog while the motor driver reconnected, and a
    survey whose data held no hyperbola raised out of the survey task; both were counted as restarts."""
    from gprbot.errors import InterpretationError

    async with running_daemon(tmp_path, use_worker=False) as (runtime, client, _, _):
        assert runtime.sim is not None and runtime.supervisor is not None
        runtime.sim.motors.unplug()
        await asyncio.sleep(2.0)  # twice the encoder task's watchdog
        runtime.sim.motors.replug()

        async def no_hyperbola(bscans: object) -> None:
            raise InterpretationError("no reflection hyperbola found to estimate the velocity from")

        runtime.survey._reconstruct = no_hyperbola  # type: ignore[method-assign,assignment]
        async with asyncio.timeout(20):
            while not runtime.motors or not runtime.motors.connected:
                await asyncio.sleep(0.1)
        assert (await client.command("survey start lines=1")).ok
        failed = await client.wait_event("survey failed", timeout_s=120)
        assert "no reflection hyperbola" in failed
        restarts = {t.name: t.restarts for t in runtime.supervisor.health()}
        assert restarts["motors.encoders"] == 0 and restarts["survey"] == 0, restarts
