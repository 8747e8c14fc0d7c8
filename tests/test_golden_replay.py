"""The golden process replay: the committed run log replays to the committed per-stage digests."""

from __future__ import annotations

import dataclasses
import json

from gprbot.apps.replay import config_from_header
from gprbot.runlog_reader import RunLogReader
from tests.golden_replay import DIGESTS, RUN_DIR, stage_digests

UPDATE = "PYTHONPATH=. .venv/bin/python -m tests.golden_replay --update"


def test_the_golden_log_is_small_and_committed() -> None:
    segments = sorted(RUN_DIR.glob("log-*.msgpack"))
    assert segments, f"no golden run log in {RUN_DIR}"
    assert sum(p.stat().st_size for p in segments) < 1_000_000


def test_every_stage_replays_to_its_committed_digest() -> None:
    expected = json.loads(DIGESTS.read_text())
    got = stage_digests()
    assert list(got) == list(expected), f"the stages themselves changed: {list(got)} vs {list(expected)}"
    moved = [stage for stage in expected if got[stage] != expected[stage]]
    assert not moved, (f"the replay changed from stage {moved[0]!r} on ({', '.join(moved)}); if the change is meant, "
                       f"update on purpose ({UPDATE}) and say why in the commit")


def test_a_change_shows_from_the_stage_it_touches_on() -> None:
    expected = json.loads(DIGESTS.read_text())
    recorded = config_from_header(RunLogReader(RUN_DIR).header)
    reseeded = dataclasses.replace(recorded, reconstruction=dataclasses.replace(recorded.reconstruction, seed=12345))
    got = stage_digests(cfg=reseeded)  # the resampling RNG: everything before the sparse cloud stays
    moved = [stage for stage in expected if got[stage] != expected[stage]]
    assert moved[0] == "sparse" and "dense.ply" in moved
    assert all(got[s] == expected[s] for s in expected if s.startswith(("poses", "bscan", "section")))
