"""The FDTD yardstick's generator and committed data (no gprMax run: the suite reads what is committed)."""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path

import pytest

from gprbot.gpr.dzt import read_dzt
from validation.fdtd.convert import DATA, INPUTS, TRUTH_KEYS, decimation
from validation.fdtd.gprmax_input import (
    DX_CHOICES_UM,
    EPS_WATER,
    WINDOW_FACTOR,
    deepest_echo_ns,
    in_sha256,
    input_text,
    layout,
)
from validation.fdtd.run import queue
from validation.fdtd.scenes import (
    C_M_PER_NS,
    N_HOLDOUT,
    N_TRAIN,
    Concrete,
    Pipe,
    Rebar,
    Scene,
    all_scenes,
    holdout_scenes,
    training_scenes,
)

SCENES = {s.name: s for s in all_scenes()}
COMMITTED = sorted(DATA.glob("*.json"))


def _scene() -> Scene:
    return Scene("t", "test", 900.0, Concrete(6.0, 0.01, (3.0, 0.3e-9)), 0.02, 40, 0.03, 0.06,
                 (Pipe(0.3, 0.2, 0.05, "pvc-water", 0.006), Pipe(0.5, 0.15, 0.02)), (Rebar(0.1, 0.05, 0.006),),
                 slab_bottom_m=0.4, below="soil")


def test_input_text_has_the_commands_of_a_2d_bscan() -> None:
    text = input_text(_scene())
    for cmd in ("#domain_mode: TM", "#domain:", "#dx_dy_dz:", "#time_window:", "#waveform: ricker 1 9e+08 src",
                "#hertzian_dipole: z", "#rx:", "#src_steps: 0.02 0 0", "#rx_steps: 0.02 0 0",
                "#add_dispersion_debye: 1 3 3e-10 concrete", "#add_dispersion_debye: 1 75.2 9.231e-12 water",
                "#material: 15 0.01 1 0 soil"):
        assert cmd in text, cmd
    cylinders = [line for line in text.splitlines() if line.startswith("#cylinder:")]
    assert [c.split()[-1] for c in cylinders] == ["pec", "pvc", "water", "pec"]  # rebar, PVC shell + bore, metal
    assert float(cylinders[1].split()[-2]) - float(cylinders[2].split()[-2]) == pytest.approx(0.006)


def test_unused_materials_are_not_defined() -> None:
    text = input_text(SCENES["metal_pipe_2600"])
    assert "water" not in text and "pvc" not in text and "soil" not in text


@pytest.mark.parametrize("name", sorted(SCENES))
def test_grid_and_window_rules(name: str) -> None:
    scene = SCENES[name]
    lay = layout(scene)
    assert round(lay.dx_m * 1e6) in DX_CHOICES_UM
    assert round(scene.step_m * 1e6) % round(lay.dx_m * 1e6) == 0  # traces land on grid cells
    lam = C_M_PER_NS * 1e9 / (2.5 * scene.frequency_mhz * 1e6) / math.sqrt(scene.concrete.eps_max())
    assert lay.dx_m <= lam / 10 + 1e-9 or lay.rule_note
    if any(p.fill == "pvc-water" for p in scene.pipes):
        assert lay.dx_m <= lam * math.sqrt(scene.concrete.eps_max() / EPS_WATER) / 6 + 1e-9 or lay.rule_note
    assert lay.time_window_ns >= WINDOW_FACTOR * (lay.source_peak_ns + deepest_echo_ns(scene))
    assert 40 <= scene.traces <= 100 and 0.01 <= scene.step_m <= 0.02
    assert 0.0 <= lay.height_m <= 0.05 and 0.02 <= lay.offset_m <= 0.10
    # the mesh batch's long lines cost more: up to 13 min each on one core, one-off
    assert lay.estimate_s(scene.traces) <= (800.0 if scene.kind == "mesh_pipe" else 300.0)
    for p in scene.pipes + scene.rebars:  # every target under the line
        assert 0.0 <= p.x_m <= scene.length_m and p.depth_m > p.radius_m  # a bar may sit under an end trace


def test_split_is_deterministic_and_balanced() -> None:
    again = all_scenes()
    assert [(s.name, s.half) for s in again] == [(s.name, s.half) for s in SCENES.values()]
    assert len(SCENES) >= 40
    halves = Counter(s.half for s in again)
    assert abs(halves["dev"] - halves["test"]) <= 1
    split = [s for s in again if s.half in ("dev", "test")]
    for kind in {s.kind for s in split}:
        assert {s.half for s in split if s.kind == kind} == {"dev", "test"}, kind
    for half in ("dev", "test"):
        freqs = [s.frequency_mhz for s in again if s.half == half]
        assert min(freqs) <= 500 and max(freqs) >= 2200


def test_queue_interleaves_halves() -> None:
    order = [s.half for s in queue(all_scenes())]
    assert order[:10] == ["dev", "test"] * 5
    assert len(order) == len(SCENES)
    # the training batch only after both halves, the holdout batch last
    assert order[-N_TRAIN - N_HOLDOUT:] == ["train"] * N_TRAIN + ["holdout"] * N_HOLDOUT


def test_the_training_batch_is_its_own_draw() -> None:
    train = training_scenes()
    assert len(train) == N_TRAIN and {s.half for s in train} == {"train"}
    assert all(s.name.startswith("train_") for s in train)
    held = [s for s in all_scenes() if s.half in ("dev", "test")]
    # no scene of either half drawn again: different names, frequencies and targets
    assert not {s.name for s in train} & {s.name for s in held}
    assert not {(s.frequency_mhz, s.pipes) for s in train} & {(s.frequency_mhz, s.pipes) for s in held}


def test_the_holdout_batch_is_a_draw_of_its_own() -> None:
    holdout = holdout_scenes()
    assert len(holdout) == N_HOLDOUT and {s.half for s in holdout} == {"holdout"}
    assert all(s.name.startswith("holdout_") for s in holdout)
    others = [s for s in all_scenes() if s.half != "holdout"]
    assert not {s.name for s in holdout} & {s.name for s in others}
    assert not {(s.frequency_mhz, s.pipes) for s in holdout} & {(s.frequency_mhz, s.pipes) for s in others}


def test_decimation_keeps_forty_samples_per_period() -> None:
    assert decimation(0.005, 1000.0) == 5
    assert decimation(0.05, 2600.0) == 1


def test_some_scenes_are_committed() -> None:
    assert len(COMMITTED) >= 2


@pytest.mark.parametrize("path", COMMITTED, ids=[p.stem for p in COMMITTED])
def test_committed_truth_matches_its_dzt(path: Path) -> None:
    record = json.loads(path.read_text())
    assert tuple(record) == TRUTH_KEYS
    scene = SCENES[record["name"]]
    assert record["half"] == scene.half and record["kind"] == scene.kind
    text = (INPUTS / f"{scene.name}.in").read_text()
    regenerate = "the generator changed: regenerate (validation/README.md)"
    assert record["in_sha256"] == in_sha256(text) == in_sha256(input_text(scene)), regenerate
    dzt_path = DATA / f"{scene.name}.DZT"
    assert dzt_path.stat().st_size < 1_000_000
    dzt = read_dzt(dzt_path)
    samples, traces = dzt.channels[0].shape
    assert traces == len(record["trace_x_m"]) == scene.traces and dzt.header.bits == 32
    assert 1.0 / dzt.header.traces_per_m == pytest.approx(scene.step_m, rel=1e-5)
    assert record["trace_x_m"][1] == pytest.approx(scene.step_m) and record["trace_x_m"][0] == 0.0
    assert dzt.header.dt_ns == pytest.approx(record["dt_ns"], rel=1e-5)
    assert dzt.header.antenna == f"{round(scene.frequency_mhz)}MHz"
    assert samples * record["dt_ns"] >= layout(scene).time_window_ns * 0.99
    assert record["velocity_m_per_ns"] == pytest.approx(C_M_PER_NS / math.sqrt(record["eps_r"]), rel=1e-4)
    assert record["antenna"]["model"] == "hertzian_dipole" and record["gprmax_version"] == "4.0.1"
    assert {tuple(p) for p in record["pipes"]} <= {("x_m", "depth_m", "radius_m", "fill", "wall_m")}
    assert all(p["fill"] in ("metal", "pvc-air", "pvc-water") for p in record["pipes"])
