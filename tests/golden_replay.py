"""The golden process replay: a short committed run log, reprocessed stage by stage, each stage's digest.

In the spirit of openpilot's process replay: `tests/data/golden_run/` is a run log recorded once (a
3-line simulated survey: traces, estimated poses, line events, < 1 MB); `tests/data/golden_digests.json`
holds a sha256 per stage of its replay — the poses read back, every line's B-scan, every line's
cross-section, the PLY clouds and pipes.json. `tests/test_golden_replay.py` checks them on every change
and names the first stage that moved. When a change is meant to move them, update on purpose with

    PYTHONPATH=. .venv/bin/python -m tests.golden_replay --update          # digests only
    PYTHONPATH=. .venv/bin/python -m tests.golden_replay --record --update # a new log, then its digests

and say in the commit which stage changed and why. `--record` is for a run-log format change only: a
new log hides what old logs replay to.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from gprbot.apps.replay import load_run, record_simulated_survey, survey_bscans
from gprbot.config import Config, load_config
from gprbot.infer.pipeline import reconstruct_survey
from gprbot.outputs.run_dir import write_survey_outputs
from gprbot.sim.scene import load_scene

DATA = Path(__file__).resolve().parent / "data"
RUN_DIR = DATA / "golden_run"
DIGESTS = DATA / "golden_digests.json"
FILES = ("sparse.ply", "dense.ply", "pipes.json")


def golden_config() -> Config:
    """The recorded survey: 3 lines of 0.6 m over paper_slab, poses from the pose-noise model (fast, small)."""
    base = load_config()
    survey = dataclasses.replace(base.survey, lines=3, length_m=0.6, speed_m_s=0.2, settle_s=0.5)
    return dataclasses.replace(base, survey=survey, sim=dataclasses.replace(base.sim, poses="noise"))


def record(run_dir: Path = RUN_DIR) -> None:
    """Record the golden run log anew (only when the run-log format itself changes)."""
    for old in run_dir.glob("log-*.msgpack"):
        old.unlink()
    record_simulated_survey(golden_config(), load_scene("paper_slab"), run_dir, created_wall_s=1.7e9)


def _sha(*parts: bytes) -> str:
    h = hashlib.sha256()
    for part in parts:
        h.update(part)
    return h.hexdigest()


def _arrays(*arrays: Any) -> str:
    return _sha(*(np.ascontiguousarray(a).tobytes() for a in arrays))


def stage_digests(run_dir: Path = RUN_DIR, cfg: Config | None = None) -> dict[str, str]:
    """Replay the log (with the recorded config, or `cfg`) and digest each stage's output, in pipeline order."""
    run = load_run(run_dir, cfg)
    poses = np.array([[p.t, *p.position, *p.orientation] for p in run.poses], dtype=np.float64)
    digests = {"poses": _arrays(poses)}
    bscans = survey_bscans(run)
    for line, bscan in sorted(bscans.items()):
        digests[f"bscan.line{line}"] = _arrays(bscan.data, bscan.positions, bscan.times)
    result = reconstruct_survey(bscans, run.config, np.random.default_rng(run.config.reconstruction_seed))
    for line_result in result.lines:
        section = line_result.section
        digests[f"section.line{line_result.line}"] = _arrays(section.mask, section.image, section.x_m, section.z_m)
    digests["sparse"] = _arrays(result.sparse)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        write_survey_outputs(out, result, {"run": "golden"}, (0.0, 1.0, 0.0, 1.0))
        for name in FILES:
            digests[name] = _sha((out / name).read_bytes())
    return digests


def main(argv: list[str] | None = None) -> int:
    """`python -m tests.golden_replay [--record] [--update]`: print (or rewrite) the stage digests."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--record", action="store_true", help="record the golden run log anew first")
    parser.add_argument("--update", action="store_true", help=f"write the digests to {DIGESTS.name}")
    args = parser.parse_args(argv)
    if args.record:
        record()
    digests = stage_digests()
    text = json.dumps(digests, indent=1, sort_keys=False) + "\n"
    if args.update:
        DIGESTS.write_text(text)
    print(text, end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
