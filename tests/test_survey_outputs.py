"""The daemon writes a survey's results in a thread while the survey task keeps feeding its watchdog."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

import gprbot.robot.survey_runner as survey_runner
from gprbot.config import load_config
from gprbot.motion.planner import plan_survey
from gprbot.robot.survey_runner import SurveyRun, SurveyRunner


async def test_writing_the_results_feeds_the_watchdog(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = load_config()
    written: list[Path] = []

    def slow_writer(out_dir: Path, *args: Any, **kwargs: Any) -> list[Path]:
        time.sleep(1.6)  # matplotlib's pictures of a 10-line survey take seconds on a loaded NUC
        written.append(out_dir)
        return []

    monkeypatch.setattr(survey_runner, "write_survey_outputs", slow_writer)
    runner = SurveyRunner(cfg, None, None, lambda text: None)  # type: ignore[arg-type]
    run = SurveyRun("r1", tmp_path / "r1", cfg.survey, plan_survey(cfg.survey))
    beats: list[float] = []
    await runner._write_outputs(run, None, lambda: beats.append(time.monotonic()))  # type: ignore[arg-type]
    assert written == [tmp_path / "r1"]
    # before: one await without beats, and the survey task's 5 s watchdog restarted it mid-write
    assert len(beats) >= 2  # at least one beat before the write ended (every 0.5 s: 3 on an idle machine)
