"""The daemon as systemd runs it, in its own process: fuzzed shells over TCP and serial, then kill -9 mid-survey
and `gprbot replay` of the torn log."""

from __future__ import annotations

import asyncio
import os
import random
import select
import signal
import socket
import subprocess
import sys
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest

from gprbot.apps.replay import replay_run
from gprbot.runlog_reader import RunLogReader
from gprbot.shell.client import ShellConnection

CONFIG = """
survey: {{lines: 4, spacing_m: 0.1, length_m: 0.6, speed_m_s: 0.2, settle_s: 0.3, start_xy_m: [0.1, 0.0]}}
sim: {{scene: paper_slab, poses: noise}}
shell: {{port: {port}, serial_console: {console}, rate_per_s: 100000.0}}
runs_dir: {runs}
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _random_line(rng: random.Random) -> bytes:
    words = ["help", "status", "stop", "jog", "survey", "pause", "files", "pull", "auth", "reset", "runs", "x=1"]
    if rng.random() < 0.5:
        text = " ".join(rng.choice([*words, str(rng.uniform(-9, 9))]) for _ in range(rng.randint(0, 5)))
        raw = text.encode()
    else:
        raw = bytes(rng.randrange(256) for _ in range(rng.randint(0, 300)))
    # Keep lines that could drive or stop the robot out of the fuzz: it runs beside a survey below.
    raw = raw.replace(b"\n", b" ").replace(b"\r", b" ")
    return b"" if raw.strip().lower().startswith((b"jog", b"survey", b"estop", b"stop", b"reset")) else raw


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[bytes], int, int, Path]]:
    master, slave = os.openpty()
    tty.setraw(master)
    port = _free_port()
    runs = tmp_path / "runs"
    config = tmp_path / "robot.yaml"
    config.write_text(CONFIG.format(port=port, console=os.ttyname(slave), runs=runs))
    log = (tmp_path / "daemon.log").open("wb")
    proc = subprocess.Popen([sys.executable, "-m", "gprbot.cli", "run", "--config", str(config)],
                            stdout=log, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 90
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            break
        except OSError:
            assert proc.poll() is None, (tmp_path / "daemon.log").read_text()
            assert time.monotonic() < deadline, "the daemon did not open its shell"
            time.sleep(0.2)
    while True:  # the shell binds before the tasks start: wait for the serial console too
        try:
            _serial_exchange(master, b"", timeout_s=1.0)
            break
        except AssertionError:
            assert proc.poll() is None, (tmp_path / "daemon.log").read_text()
            assert time.monotonic() < deadline, "the daemon did not open its serial console"
    yield proc, port, master, runs
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    log.close()
    os.close(master)
    os.close(slave)


def _serial_exchange(master: int, line: bytes, timeout_s: float = 10.0) -> bytes:
    """Write one line to the serial console and read until its `ok`/`error` reply line."""
    os.write(master, line + b"\n")
    buffer = b""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.5)
        if ready:
            buffer += os.read(master, 65536)
            for reply in buffer.split(b"\n"):
                if reply.startswith((b"ok", b"error")):
                    return reply
    raise AssertionError(f"no reply on the serial console to {line!r}; got {buffer!r}")


@pytest.mark.timeout(300)
def test_fuzzed_shells_then_kill_9_mid_survey_and_replay(
    daemon: tuple[subprocess.Popen[bytes], int, int, Path], tmp_path: Path
) -> None:
    proc, port, master, runs = daemon
    rng = random.Random(7)

    async def fuzz_tcp_then_start_survey() -> str:
        events: list[str] = []
        async with ShellConnection("127.0.0.1", port, events.append) as shell:
            for _ in range(1500):
                reply = await shell.request(_random_line(rng).decode("utf-8", "replace"))
                assert reply.ok or reply.code  # every line gets exactly one ok/error reply
            assert (await shell.check("status")).ok
            run = (await shell.check("survey start")).text.split()[1]
            while not any(e.startswith("line 2 start") for e in events):
                await asyncio.sleep(0.1)
            return run

    for _ in range(300):
        reply = _serial_exchange(master, _random_line(rng))
        assert reply.startswith((b"ok", b"error"))
    assert _serial_exchange(master, b"status").startswith(b"ok")

    run = asyncio.run(fuzz_tcp_then_start_survey())
    assert proc.poll() is None, "the fuzz killed the daemon"
    time.sleep(1.0)
    proc.send_signal(signal.SIGKILL)  # power loss: no shutdown, no end marker, maybe a torn record
    proc.wait()

    reader = RunLogReader(runs / run)
    reader.scan()
    assert not reader.ended
    result = replay_run(runs / run, tmp_path / "replayed")
    assert len(result.lines) >= 2  # lines 0 and 1 were complete before the kill
    assert (tmp_path / "replayed" / "dense.ply").exists()
