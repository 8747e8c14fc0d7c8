"""What a run's output files cost: each picture, the exports and the MCAP export, for a 10-line survey.

Prints the median (of 3) wall time of each writer on the default 10-line paper_slab survey (poses from
the noise model, so the simulation is quick): B-scan and section PNGs per line (matplotlib, Agg), the
map, the depth slices, the 3D render, DXF + CSV + GeoJSON, and `export_mcap` of the recorded log
(records/s). The daemon writes these in a worker thread after the survey, never on the event loop.
Run: `.venv/bin/python -m benchmarks.bench_outputs`.
"""

from __future__ import annotations

import dataclasses
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmarks.machine import machine_description
from gprbot.apps.replay import load_run, record_simulated_survey, survey_bscans
from gprbot.config import GeoreferenceConfig, load_config, to_dict
from gprbot.exports.mcap_log import export_mcap
from gprbot.gpr.render import write_bscan_png, write_cross_section_png
from gprbot.infer.pipeline import reconstruct_survey
from gprbot.outputs.depth_slices import depth_bands, depth_slices, render_depth_slices
from gprbot.outputs.render3d import render_3d
from gprbot.outputs.run_dir import velocity_note, write_exports
from gprbot.outputs.topdown import render_topdown
from gprbot.runlog_reader import RunLogReader
from gprbot.sim.scene import load_scene


def median_s(work: Callable[[], object], repeats: int = 3) -> float:
    """Median wall time of `work` over repeats."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        work()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    """Measure and print."""
    print(machine_description())
    base = load_config()
    geo = GeoreferenceConfig(heading_deg=30.0, origin_lat_deg=47.3769, origin_lon_deg=8.5417)
    cfg = dataclasses.replace(base, sim=dataclasses.replace(base.sim, poses="noise"), georeference=geo)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        record_simulated_survey(cfg, load_scene("paper_slab"), root / "run", 1.7e9)
        bscans = survey_bscans(load_run(root / "run", cfg))
        result = reconstruct_survey(bscans, cfg, np.random.default_rng(0))
        out = root / "out"
        out.mkdir()
        note = velocity_note(result)
        lr = result.lines[1]
        extent = (-0.2, 2.2, -0.2, 1.1)
        lines_xy = [line.bscan.positions[:, :2] for line in result.lines]
        figures = {
            "B-scan PNG (one line)": lambda: write_bscan_png(out / "b.png", lr.bscan, result.velocity_m_per_ns, note),
            "section PNG (one line)": lambda: write_cross_section_png(out / "s.png", lr.section, None, lr.bscan, note),
            "map.png (cv2)": lambda: render_topdown(out / "m.png", result.reconstruction, extent, [], lines_xy),
            "depth slices (6 bands)": lambda: render_depth_slices(
                out / "d.png", result, depth_slices(result, depth_bands(0.6), extent), note),
            "3D render": lambda: render_3d(out / "r.png", result.reconstruction, lines_xy),
            "DXF + CSV + GeoJSON": lambda: write_exports(out, result, {"run": "bench", "config": to_dict(cfg)}),
        }
        print(f"{len(result.lines)} lines, {len(result.reconstruction.pipes)} pipes, "
              f"{len(result.reconstruction.dense)} dense points")
        total = 0.0
        for name, work in figures.items():
            seconds = median_s(work)
            per_run = seconds * (len(result.lines) if "one line" in name else 1)
            total += per_run
            print(f"  {name:26s} {seconds * 1e3:8.0f} ms   ({per_run:.2f} s per run)")
        print(f"  all pictures and exports of the run: {total:.1f} s")
        records = sum(1 for _ in RunLogReader(root / "run"))
        seconds = median_s(lambda: export_mcap(root / "run", root / "run.mcap"))
        size = (root / "run.mcap").stat().st_size
        print(f"  export-mcap: {records} records in {seconds:.2f} s ({records / seconds:,.0f} records/s), "
              f"{size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
