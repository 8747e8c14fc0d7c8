"""Inference worker: same results as in-process, survives kill -9, keeps the event loop responsive."""

from __future__ import annotations

import asyncio
import dataclasses
import os
import signal
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gprbot.config import Config, load_config, to_dict
from gprbot.errors import GprbotError
from gprbot.gpr.bscan import BScan
from gprbot.gpr.preprocess import preprocess
from gprbot.infer.pipeline import interpret_line, reconstruct_survey
from gprbot.infer.worker import InferenceWorker
from gprbot.reconstruct.survey_result import SurveyResult
from gprbot.sim.scene import load_scene
from gprbot.simulated.survey import simulate_survey
from gprbot.survey import assemble_bscan, line_windows, split_by_line


@pytest.fixture(scope="module")
def survey() -> tuple[Config, dict[int, BScan], SurveyResult]:
    """A 3-line simulated survey over paper_slab, its B-scans and the in-process reconstruction."""
    base = load_config()
    cfg = dataclasses.replace(base, survey=dataclasses.replace(base.survey, lines=3, length_m=1.0))
    sim = simulate_survey(cfg, load_scene("paper_slab"))
    by_line = split_by_line(sim.traces, line_windows(sim.plan))
    lever = cfg.mount.antenna_lever_arm_m
    bscans = {line: assemble_bscan(tr, sim.trajectory.estimated_poses, lever) for line, tr in by_line.items()}
    return cfg, bscans, reconstruct_survey(bscans, cfg, np.random.default_rng(cfg.reconstruction_seed))


def assert_same_survey(got: SurveyResult, want: SurveyResult) -> None:
    """Bit-identical reconstruction: velocity, clouds, pipes and every line's mask."""
    assert got.velocity_m_per_ns == want.velocity_m_per_ns
    assert np.array_equal(got.sparse, want.sparse)
    assert np.array_equal(got.reconstruction.dense, want.reconstruction.dense)
    assert len(got.reconstruction.pipes) == len(want.reconstruction.pipes) > 0
    for a, b in zip(got.reconstruction.pipes, want.reconstruction.pipes, strict=True):
        assert np.array_equal(a.axis, b.axis) and a.diameter_m == b.diameter_m
    for a, b in zip(got.lines, want.lines, strict=True):
        assert a.line == b.line and np.array_equal(a.section.mask, b.section.mask)


async def _kill_when_busy(worker: InferenceWorker, times: int) -> list[int]:
    """kill -9 the worker each time it is computing a job, `times` times (each time a new process)."""
    killed: list[int] = []
    while len(killed) < times:
        health = worker.health()
        if health.busy and health.pid is not None and health.pid not in killed:
            os.kill(health.pid, signal.SIGKILL)
            killed.append(health.pid)
        await asyncio.sleep(0.005)
    return killed


async def test_worker_matches_in_process_and_keeps_the_loop_responsive(survey: Any, tmp_path: Path) -> None:
    cfg, bscans, want = survey
    worker = InferenceWorker(cfg)
    await worker.start()
    try:
        lags: list[float] = []

        async def ticker() -> None:
            loop = asyncio.get_running_loop()
            expected = loop.time() + 0.01
            while True:
                await asyncio.sleep(0.01)
                lags.append(loop.time() - expected)
                expected = loop.time() + 0.01

        ticks = asyncio.create_task(ticker())
        got = await worker.finish_survey(bscans)
        line = await worker.interpret_line(1, bscans[1], want.velocity_m_per_ns)
        estimate = await worker.interpret_line(2, bscans[2], None)
        ticks.cancel()
        # the run directory is written in the worker: matplotlib's pictures never hold the daemon's GIL
        written = await worker.write_outputs(tmp_path / "run", got, {"run": "run", "config": to_dict(cfg)},
                                             (-0.2, 1.2, -0.2, 0.4), [], bscans)
        assert {"pipes.json", "pipes.dxf", "bscan_line01.png", "depth_slices.png"} <= {p.name for p in written}
        assert all(p.is_file() for p in written)
        assert_same_survey(got, want)
        assert len(lags) > 50 and max(lags) < 0.2, f"max event-loop lag {max(lags):.3f} s"
        assert 0 < got.timings_s["worker_compute"] <= got.timings_s["round_trip"]
        assert {"preprocess", "velocity", "interpret"} <= set(got.timings_s)

        processed = preprocess(bscans[1], cfg.gpr)
        direct = interpret_line(1, processed, cfg, want.velocity_m_per_ns)
        assert line.velocity_source == "hint" and line.velocity_m_per_ns == want.velocity_m_per_ns
        assert np.array_equal(line.section.mask, direct.section.mask)
        assert np.array_equal(line.slice.points, direct.slice.points)
        assert line.bscan.n_traces == bscans[1].data.shape[0] and line.bscan.processing == processed.processing
        assert line.timings_s["round_trip"] >= line.timings_s["interpret"] > 0
        assert estimate.velocity_source in {"line estimate", "default guess"}
        assert 0.05 < estimate.velocity_m_per_ns < 0.3

        health = worker.health()
        assert health.alive and health.jobs_done == 4 and health.restarts == 0 and health.jobs_failed == 0
        assert health.last_timings_s == estimate.timings_s

        in_flight = asyncio.create_task(worker.finish_survey(bscans))
        while not worker.health().busy:
            await asyncio.sleep(0.005)
        await worker.close()  # shutdown does not wait for the job: it fails at once
        with pytest.raises(GprbotError, match="closed during"):
            await in_flight
    finally:
        await worker.close()
    assert not worker.health().alive
    with pytest.raises(GprbotError, match="closed"):
        await worker.interpret_line(0, bscans[0], 0.1)


async def test_killed_worker_is_restarted_retried_and_timeouts_recover(survey: Any) -> None:
    cfg, bscans, _ = survey
    direct = interpret_line(1, preprocess(bscans[1], cfg.gpr), cfg, 0.1)
    worker = InferenceWorker(cfg)
    await worker.start()
    try:
        first_pid = worker.health().pid
        killer = asyncio.create_task(_kill_when_busy(worker, 1))
        got = await worker.interpret_line(1, bscans[1], 0.1)
        assert await killer == [first_pid]
        assert np.array_equal(got.section.mask, direct.section.mask)
        assert np.array_equal(got.slice.points, direct.slice.points)
        health = worker.health()
        assert health.restarts == 1 and health.alive and health.pid != first_pid and health.jobs_done == 1
        assert "died" in health.last_error

        killer = asyncio.create_task(_kill_when_busy(worker, 2))
        with pytest.raises(GprbotError, match="died twice on line 0"):
            await worker.interpret_line(0, bscans[0], 0.1)
        assert len(await killer) == 2
        health = worker.health()
        assert health.restarts == 3 and health.jobs_failed == 1 and health.alive

        worker.job_timeout_s = 0.05
        with pytest.raises(GprbotError, match=r"ran past 0\.05 s"):
            await worker.finish_survey(bscans)
        assert worker.health().restarts == 4 and worker.health().alive
        worker.job_timeout_s = 60.0
        empty = dataclasses.replace(bscans[0], data=bscans[0].data[:2], positions=bscans[0].positions[:2],
                                    times=bscans[0].times[:2])
        with pytest.raises(GprbotError) as caught:
            await worker.interpret_line(0, empty, 0.1)
        assert type(caught.value).__name__ == "InterpretationError"
        again = await worker.interpret_line(0, bscans[0], 0.1)  # the worker still serves the next job
        assert again.line == 0 and again.velocity_source == "hint"
        health = worker.health()
        assert health.restarts == 4 and health.jobs_failed == 3 and health.jobs_done == 2
    finally:
        await worker.close()
