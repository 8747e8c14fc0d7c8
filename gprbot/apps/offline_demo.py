"""`gprbot demo --offline`: a whole simulated survey processed directly (no daemon), from driving the lines to
pipes.json, checked against truth."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gprbot import __version__, progress
from gprbot.config import Config, to_dict
from gprbot.infer.pipeline import reconstruct_survey, survey_steps
from gprbot.motion.planner import survey_region as planned_region
from gprbot.outputs.report_html import write_report_safely
from gprbot.outputs.run_dir import write_survey_outputs
from gprbot.reconstruct.survey_result import SurveyResult
from gprbot.sim.scene import Scene
from gprbot.sim.truth import cross_section_mask
from gprbot.simulated.evaluation import PipeMatch, compare_to_truth, format_truth_table, within_bounds
from gprbot.simulated.survey import simulate_survey
from gprbot.survey import assemble_bscan, line_windows, split_by_line


@dataclass(frozen=True)
class DemoResult:
    """What one demo run produced and how it compares with the scene's truth."""

    out_dir: Path
    result: SurveyResult
    matches: list[PipeMatch]
    extras: list[int]
    table: str
    ok: bool
    seconds: float


def survey_region(cfg: Config) -> tuple[float, float, float, float]:
    """The area the antenna covers: (xmin, xmax, ymin, ymax) in the site frame."""
    s = cfg.survey
    return planned_region(s.start_xy_m, s.length_m, s.lines, s.spacing_m)


def run_demo(cfg: Config, scene: Scene, out_dir: Path) -> DemoResult:
    """Simulate a survey over `scene`, reconstruct it, write the run directory, compare with truth."""
    start = time.perf_counter()
    # steps: the simulation (sensors, VO and the filter: most of the time), the survey's, the outputs
    with progress.bar(survey_steps(cfg.survey.lines) + 2, f"{scene.name}: simulating sensors, VO") as steps:

        def step(what: str) -> None:
            steps.set_description(f"{scene.name}: {what}")
            steps.update()

        sim = simulate_survey(cfg, scene)
        step("simulated")
        by_line = split_by_line(sim.traces, line_windows(sim.plan))
        lever = cfg.mount.antenna_lever_arm_m
        bscans = {line: assemble_bscan(tr, sim.trajectory.estimated_poses, lever) for line, tr in by_line.items()}
        result = reconstruct_survey(bscans, cfg, np.random.default_rng(cfg.reconstruction_seed), step)
        steps.set_description(f"{scene.name}: writing the run directory")
        region = survey_region(cfg)
        matches, extras = compare_to_truth(result.reconstruction.pipes, scene, region)
        table = format_truth_table(matches, extras, result.reconstruction.pipes)

        # Truth masks are drawn at the TRUE antenna positions of each line's columns.
        truth_masks = {}
        for lr in result.lines:
            times = np.interp(lr.section.x_m, lr.bscan.along_track_m(), lr.bscan.times)
            truth_masks[lr.line] = cross_section_mask(scene, sim.trajectory.true_antenna_xy(times), lr.section.z_m)

        meta = {
            "run": out_dir.name,
            "gprbot_version": __version__,
            "scene": scene.name,
            "frame": "site: x forward along the survey lines, y left, z up; metres",
            "config": to_dict(cfg),
        }
        region_pad = (region[0] - 0.2, region[1] + 0.2, region[2] - 0.2, region[3] + 0.2)
        write_survey_outputs(out_dir, result, meta, region_pad, [p.points for p in scene.pipes], truth_masks, bscans)
        write_report_safely(out_dir)  # report.html: the console's results page, self-contained
        step("written")
    ok = within_bounds(matches)
    return DemoResult(out_dir, result, matches, extras, table, ok, time.perf_counter() - start)
