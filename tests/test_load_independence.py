"""Issue 15 #10: what made survey results depend on CPU load — a fusion backlog drained in one go held the
event loop past the motor link's reply timeout — is bounded: the loop gets control every few messages."""

from __future__ import annotations

import asyncio
import types
from pathlib import Path

import numpy as np
import pytest

from gprbot.config import load_config
from gprbot.messages import ImuSample
from gprbot.robot import fusion_state
from gprbot.robot.fusion_state import FusionState


async def test_a_fusion_backlog_is_drained_in_slices_that_let_other_tasks_run() -> None:
    fusion = FusionState(load_config(), (0.0, 0.0, 0.0))
    for k in range(1000):  # a second's backlog after a stall: 400 Hz gyro + 250 Hz accel + encoders
        fusion.submit(ImuSample(k * 0.0025, gyro=np.zeros(3)))
    seen: list[int] = []

    async def other_task() -> None:
        while fusion.messages < 1000:
            seen.append(fusion.messages)
            await asyncio.sleep(0)

    watcher = asyncio.create_task(other_task())
    runner = asyncio.create_task(fusion.run(lambda: None))
    async with asyncio.timeout(30):
        await watcher
    runner.cancel()
    jumps = np.diff([0, *seen, fusion.messages])
    assert jumps.max() <= getattr(fusion_state, "MAX_BATCH", 20)


def test_gprbot_demo_exits_non_zero_when_its_truth_check_fails(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from gprbot import cli
    from gprbot.apps import offline_demo as demo

    result = types.SimpleNamespace(lines=[], reconstruction=types.SimpleNamespace(pipes=[]), velocity_estimated=False,
                                   velocity_m_per_ns=0.1)
    monkeypatch.setattr(demo, "run_demo", lambda cfg, scene, out: types.SimpleNamespace(
        result=result, seconds=0.0, table="(no pipes)", ok=False, out_dir=out, matches=[], extras=[]))
    assert cli.main(["demo", "--offline", "--out", str(tmp_path)]) == 3
    assert "within bounds (3 cm position and depth, 30 % diameter): NO" in capsys.readouterr().out
