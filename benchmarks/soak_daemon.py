"""Soak: the daemon (its own process, as systemd runs it) on the simulated robot for a long time, surveying,
while eight abusive clients hammer its TCP shell and one operator works it.

Abusers: idle connections, slowloris (a byte a second), long lines, random bytes, wrong tokens,
unauthenticated e-stop floods (a burst every 60 s), a stalled pull (authenticated, never reads) and
connection churn. The operator holds one authenticated session: a survey is always running; every
`--estop-every` seconds it sends `estop` (round trip timed; the daemon's reply says when the wheels
were commanded to 0 and confirmed), then `reset` and `survey resume`; it also clears e-stops the flood
latched. Printed: e-stop round trip (median, p99, max), wheels-stopped latency, the daemon's memory
(RSS) growth after warm-up, watchdog restarts (from `status`), and lost records (skipped or torn
records of every run log, runs not ended). Goal (issue 15): p99 <= 50 ms, max <= 100 ms, growth
<= 10 MiB, 0 restarts, 0 lost records. On memory: growth is counted from the end of a warm-up of
WARM_UP_S, by which the first two surveys have run and every abuser has been through its cycle once
(the flood and the stalled pull come every 60 s): what a daemon allocates the first time it does
something (its first survey: +65 MiB) is a one-off, a leak is what keeps growing after. The growth
from the first sample and the slope over the second half are printed too, and the per-minute RSS
timeline is in the JSON. (The pose history is preallocated, so it does not fill up during the soak.)

Run: `python -m benchmarks.soak_daemon --minutes 15 [--json OUT]`.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import random
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.machine import machine_description
from gprbot.runlog_reader import RunLogReader
from gprbot.shell.client import ShellConnection

TOKEN = "soak-token-0123456789-abcdef"
CONFIG = """
survey: {{lines: 6, spacing_m: 0.1, length_m: 1.0, speed_m_s: 0.2, settle_s: 0.5, start_xy_m: [0.1, 0.0]}}
sim: {{scene: paper_slab, poses: noise}}
shell: {{host: 127.0.0.1, port: {port}, token_file: {token}}}
runs_dir: {runs}
"""
WHEELS = re.compile(r"wheels stopped in ([0-9.]+) ms")
WARM_UP_S = 120.0


def free_port() -> int:
    """A free TCP port on loopback."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def rss_mib(pid: int) -> float:
    """Resident memory of a process (MiB)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


async def abuser(kind: str, port: int, stop: asyncio.Event, counts: dict[str, int]) -> None:
    """One abusive client of `kind`, reconnecting whenever the daemon drops it."""
    rng = random.Random(kind)
    while not stop.is_set():
        try:
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
        except OSError:
            await asyncio.sleep(0.5)
            continue
        counts[kind] = counts.get(kind, 0) + 1
        try:
            if kind == "idle":
                async with asyncio.timeout(60):
                    await reader.read()
            elif kind == "slowloris":
                for _ in range(60):
                    writer.write(b"s")
                    await writer.drain()
                    await asyncio.sleep(1.0)
            elif kind == "long-lines":
                for _ in range(200):
                    writer.write(b"x" * 2000 + b"\n")
                    await writer.drain()
                    await asyncio.sleep(0.05)
            elif kind == "random-bytes":
                for _ in range(200):
                    writer.write(bytes(rng.randrange(256) for _ in range(rng.randint(1, 500))))
                    await writer.drain()
                    await asyncio.sleep(0.05)
            elif kind == "wrong-tokens":
                for _ in range(10):
                    writer.write(f"auth guess-{rng.getrandbits(64):016x}-xxxxxx\n".encode())
                    await writer.drain()
                    await asyncio.sleep(0.1)
            elif kind == "estop-flood":
                await asyncio.sleep(60.0)
                for _ in range(20):  # 20 000 unauthenticated e-stops in about a second
                    writer.write(b"estop\n" * 1000)
                    await writer.drain()
                    await asyncio.sleep(0.05)
            elif kind == "stalled-pull":
                writer.write(f"auth {TOKEN}\npull big big.bin\n".encode())
                await writer.drain()
                await asyncio.sleep(60.0)  # never reads the 64 MiB it asked for
            elif kind == "churn":
                await asyncio.sleep(rng.uniform(0.05, 0.3))
        except (OSError, TimeoutError, asyncio.IncompleteReadError):
            pass
        finally:
            writer.close()
            with contextlib.suppress(OSError, TimeoutError):
                async with asyncio.timeout(2.0):
                    await writer.wait_closed()
        await asyncio.sleep(0.2)


async def operator(port: int, stop: asyncio.Event, estop_every_s: float, out: dict[str, list[float]]) -> None:
    """The operator: one authenticated session, a survey always running, e-stops timed."""
    async with ShellConnection("127.0.0.1", port, lambda event: None) as shell:
        await shell.authenticate(TOKEN)
        next_estop = time.monotonic() + estop_every_s
        while not stop.is_set():
            status = await shell.request("status")
            body = "\n".join(status.body)
            if "estop latched" in body:  # the flood latched it: clear and carry on
                await shell.request("reset")
                await shell.request("survey resume")
            if "survey " not in body or " done " in body or " failed " in body or " aborted " in body:
                reply = await shell.request("survey start")
                if reply.ok:
                    out.setdefault("runs", []).append(reply.text.split()[1])  # type: ignore[arg-type]
            if time.monotonic() >= next_estop:
                began = time.perf_counter()
                reply = await shell.request("estop")
                out["estop_rtt_s"].append(time.perf_counter() - began)
                match = WHEELS.search(reply.text)
                if match:
                    out["wheels_stopped_s"].append(float(match.group(1)) / 1000)
                await shell.request("reset")
                await shell.request("survey resume")
                next_estop += estop_every_s
            await asyncio.sleep(1.0)
        final = await shell.request("status")
        out["restarts"] = [float(sum(int(m.group(1)) for line in final.body
                                     if (m := re.match(r"task \S+ \S+ restarts (\d+)", line))))]
        out["status"] = list(final.body)  # type: ignore[arg-type]


async def soak(minutes: float, estop_every_s: float, json_out: Path | None) -> None:
    """Run the soak; print the figures."""
    with tempfile.TemporaryDirectory(prefix="gprbot-soak-") as tmp:
        root = Path(tmp)
        runs = root / "runs"
        (runs / "big").mkdir(parents=True)
        with (runs / "big" / "big.bin").open("wb") as big:
            big.write(os.urandom(1 << 20) * 64)
        token = root / "token"
        token.write_text(TOKEN + "\n")
        token.chmod(0o600)
        port = free_port()
        config = root / "robot.yaml"
        config.write_text(CONFIG.format(port=port, token=token, runs=runs))
        log = (root / "daemon.log").open("wb")
        proc = subprocess.Popen([sys.executable, "-m", "gprbot.cli", "run", "--config", str(config)],
                                stdout=log, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 120
            while True:
                with contextlib.suppress(OSError):
                    socket.create_connection(("127.0.0.1", port), timeout=1).close()
                    break
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise SystemExit("the daemon did not start:\n" + (root / "daemon.log").read_text())
                await asyncio.sleep(0.5)
            await asyncio.sleep(3.0)
            stop = asyncio.Event()
            counts: dict[str, int] = {}
            kinds = ["idle", "slowloris", "long-lines", "random-bytes", "wrong-tokens", "estop-flood",
                     "stalled-pull", "churn"]
            out: dict[str, list[float]] = {"estop_rtt_s": [], "wheels_stopped_s": []}
            tasks = [asyncio.create_task(abuser(k, port, stop, counts)) for k in kinds]
            op = asyncio.create_task(operator(port, stop, estop_every_s, out))
            memory: list[tuple[float, float]] = []
            began = time.monotonic()
            while time.monotonic() - began < minutes * 60:
                if op.done():
                    op.result()  # the operator failed: show why
                memory.append((time.monotonic() - began, rss_mib(proc.pid)))
                await asyncio.sleep(10.0)
            stop.set()
            async with asyncio.timeout(60):
                await op
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            alive = proc.poll() is None
            proc.terminate()
            exit_status = proc.wait(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            log.close()
        lost = torn = not_ended = 0
        for run in out.get("runs", []):
            reader = RunLogReader(runs / str(run)).scan()
            lost += reader.skipped
            torn += reader.torn
            not_ended += not reader.ended
        report(minutes, out, memory, counts, alive, exit_status, lost, torn, not_ended, json_out,
               (root / "daemon.log").read_text())


def report(minutes: float, out: dict[str, list[float]], memory: list[tuple[float, float]], counts: dict[str, int],
           alive: bool, exit_status: int, lost: int, torn: int, not_ended: int, json_out: Path | None,
           daemon_log: str) -> None:
    """Print (and optionally save) the soak's figures."""
    rtt = np.array(out["estop_rtt_s"]) * 1000
    wheels = np.array(out["wheels_stopped_s"]) * 1000
    times, rss = np.array([t for t, _ in memory]), np.array([m for _, m in memory])
    after_warm_up = rss[(times >= WARM_UP_S) & (times < WARM_UP_S + 60.0)]
    warm = after_warm_up if after_warm_up.size else rss[-1:]  # a soak shorter than the warm-up: no growth to see
    late = rss[-max(1, len(rss) // 10):]
    growth = float(statistics.median(late) - statistics.median(warm))
    second_half = times >= times[-1] / 2
    slope = float(np.polyfit(times[second_half] / 60.0, rss[second_half], 1)[0]) if second_half.sum() > 2 else 0.0
    figures = {
        "minutes": minutes, "machine": machine_description(),
        "estop_rtt_ms": {"n": int(rtt.size), "median": float(np.median(rtt)), "p99": float(np.percentile(rtt, 99)),
                         "max": float(rtt.max())} if rtt.size else None,
        "wheels_stopped_ms": {"n": int(wheels.size), "median": float(np.median(wheels)),
                              "p99": float(np.percentile(wheels, 99)), "max": float(wheels.max())}
        if wheels.size else None,
        "rss_mib": {"first": float(rss[0]), "warm_up_s": WARM_UP_S,
                    "after_warm_up_median": float(statistics.median(warm)),
                    "late_median": float(statistics.median(late)), "max": float(rss.max()), "growth": growth,
                    "growth_from_first_sample": float(statistics.median(late) - rss[0]),
                    "slope_second_half_mib_per_min": slope,
                    "timeline": [[round(t), round(m, 1)] for t, m in memory[::6]]},  # every minute
        "watchdog_restarts": int(out.get("restarts", [float("nan")])[0]),
        "runs": len(out.get("runs", [])), "lost_records": lost, "torn_logs": torn, "runs_not_ended": not_ended,
        "abuser_connections": counts, "daemon_alive_at_end": alive, "exit_status_after_sigterm": exit_status,
        "daemon_log_lines": len(daemon_log.splitlines()),
        "daemon_tracebacks": daemon_log.count("Traceback"),
        # the log lives in a temporary directory: keep what each traceback said (its last lines)
        "daemon_traceback_tails": [block.strip().splitlines()[-3:] for block in daemon_log.split("Traceback")[1:6]],
    }
    print(json.dumps(figures, indent=2))
    print("status at the end:\n  " + "\n  ".join(str(line) for line in out.get("status", [])))
    if json_out is not None:
        json_out.write_text(json.dumps(figures, indent=2))


def main() -> None:
    """Parse the arguments and run the soak."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--estop-every", type=float, default=5.0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    asyncio.run(soak(args.minutes, args.estop_every, args.json))


if __name__ == "__main__":
    main()
