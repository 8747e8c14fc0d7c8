"""MigrationNet: depth conversion against analytic depth, tiling, blobs, training smoke test, ONNX round trip."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from gprbot.config import GprConfig, InterpretationConfig
from gprbot.errors import ModelError
from gprbot.gpr.bscan import BScan
from gprbot.gpr.traveltime import velocity_from_eps
from gprbot.infer.migrationnet import (
    COLS,
    DX_M,
    DZ_M,
    ROWS,
    MigrationNetInterpreter,
    blobs_to_detections,
    cut_tiles,
    depth_grid,
    depth_section,
    stitch,
)
from gprbot.sim.forward import simulate_bscan
from gprbot.sim.scene import Pipe, Scene, Slab

torch = pytest.importorskip("torch")
ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "models" / "migrationnet.onnx"

EPS_R = 7.0
PIPE_X, PIPE_DEPTH, PIPE_RADIUS = 0.8, 0.25, 0.03


def _one_pipe_line() -> tuple[BScan, GprConfig]:
    """A 1.6 m line over one steel pipe at x = 0.8 m, axis 0.25 m deep, crossing at right angles."""
    slab = Slab((2.0, 1.0), (-0.2, -0.5), 0.5, EPS_R, 10.0)
    pipe = Pipe("steel", np.array([[PIPE_X, -0.5, -PIPE_DEPTH], [PIPE_X, 0.5, -PIPE_DEPTH]]), PIPE_RADIUS, "metal")
    scene = Scene("one", "", slab, (pipe,), None, None)
    gpr = GprConfig(noise_mv=0.2)
    xy = np.stack([np.arange(0.0, 1.6, 0.005), np.zeros(320)], axis=1)
    data = simulate_bscan(scene, xy, gpr, np.random.default_rng(0))
    positions = np.concatenate([xy, np.zeros((len(xy), 1))], axis=1)
    return BScan(data, gpr.dt_ns, gpr.pre_trigger_ns, positions, np.arange(len(xy)) * 0.05), gpr


def test_depth_section_puts_the_pipe_top_at_its_true_depth() -> None:
    bscan, gpr = _one_pipe_line()
    image, x = depth_section(bscan, gpr, velocity_from_eps(EPS_R))
    assert image.shape == (ROWS, len(x)) and image.dtype == np.float32
    assert x[1] - x[0] == pytest.approx(DX_M) and np.abs(image).max() <= 5.0
    column = int(np.argmin(np.abs(x - PIPE_X)))
    envelope = np.abs(image[:, column - 1:column + 2]).max(axis=1)
    top = depth_grid()[int(np.argmax(envelope))]
    assert top == pytest.approx(PIPE_DEPTH - PIPE_RADIUS, abs=0.02)  # within a quarter wavelength
    strength = np.abs(image).max(axis=0)
    strong = strength >= 0.9 * strength.max()  # the hyperbola is symmetric about its apex
    assert np.mean(x[strong]) == pytest.approx(PIPE_X, abs=0.03)


def test_tiles_stitch_back_to_the_image() -> None:
    for width in (40, COLS, 300):
        image = np.random.default_rng(width).random((ROWS, width)).astype(np.float32)
        tiles, starts = cut_tiles(image)
        assert tiles.shape == (len(starts), 1, ROWS, COLS) and starts[0] == 0
        assert starts[-1] + COLS >= width
        np.testing.assert_allclose(stitch(tiles, starts, width), image, rtol=1e-6)


def test_a_disc_of_probability_becomes_one_detection() -> None:
    z = depth_grid()
    x = np.arange(150) * DX_M
    disc = ((x[None, :] - 0.7) / 0.05) ** 2 + ((z[:, None] - 0.3) / 0.05) ** 2 <= 1.0
    speck = np.zeros_like(disc)
    speck[10, 10] = True
    probability = np.where(disc, 0.9, np.where(speck, 0.8, 0.05)).astype(np.float32)
    mask, detections = blobs_to_detections(probability, x, z)
    assert len(detections) == 1 and not mask[10, 10]
    d = detections[0]
    assert (d.x_m, d.depth_m) == (pytest.approx(0.7, abs=DX_M), pytest.approx(0.3, abs=DZ_M))
    assert d.radius_m == pytest.approx(0.05, abs=DZ_M) and d.score == pytest.approx(0.9)
    assert d.radius_from_mask  # the picture marks it "(mask)": a blob's size is not a measured radius


def test_a_blob_the_network_is_unsure_of_leaves_the_mask() -> None:
    z = depth_grid()
    x = np.arange(150) * DX_M
    sure = ((x[None, :] - 0.4) / 0.04) ** 2 + ((z[:, None] - 0.2) / 0.04) ** 2 <= 1.0
    unsure = ((x[None, :] - 1.1) / 0.04) ** 2 + ((z[:, None] - 0.3) / 0.04) ** 2 <= 1.0
    probability = np.where(sure, 0.95, np.where(unsure, 0.6, 0.05)).astype(np.float32)
    mask, detections = blobs_to_detections(probability, x, z, 0.4, min_peak=0.7)
    assert [round(d.x_m, 1) for d in detections] == [0.4]
    assert mask[sure].all() and not mask[unsure].any()


def test_the_calibrated_minimum_peak_keeps_every_true_blob() -> None:
    from training.train_migrationnet import min_peak_keeping, true_blob_peaks

    p = np.zeros((1, 20, 20))
    p[0, 2:5, 2:5], p[0, 10:13, 10:13], p[0, 15:18, 2:5] = 0.83, 0.97, 0.99
    truth = np.zeros((1, 20, 20), dtype=bool)
    truth[0, 3, 3] = truth[0, 11, 11] = True  # the third blob is on no pipe: it does not count
    peaks = true_blob_peaks(p, truth, 0.4)
    assert sorted(np.round(peaks, 2)) == [0.83, 0.97]
    assert min_peak_keeping(peaks) == 0.8 and min_peak_keeping(np.array([])) == 0.0

def test_a_few_training_steps_reduce_the_loss() -> None:
    from training.migration_data import scene_tiles
    from training.migrationnet import MigrationNet, bce_dice_loss

    torch.set_num_threads(1)
    torch.manual_seed(0)
    x, y = scene_tiles(0, "train")
    rows, cols = np.nonzero(y[0, 0])
    r0 = int(np.clip(rows.mean() - 32, 0, ROWS - 64))
    c0 = int(np.clip(cols.mean() - 32, 0, COLS - 64))
    window = (slice(0, 2), slice(None), slice(r0, r0 + 64), slice(c0, c0 + 64))  # 64×64 around the pipe: fast
    xb, yb = torch.from_numpy(x[window].astype(np.float32)), torch.from_numpy(y[window].astype(np.float32))
    assert yb.sum() > 0  # the chosen tiles show the pipe
    net = MigrationNet(width=4)
    optimiser = torch.optim.Adam(net.parameters(), lr=1e-2)
    losses = []
    for _ in range(10):
        loss = bce_dice_loss(net(xb), yb)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
    assert net(xb).shape == yb.shape
    assert losses[-1] < 0.85 * losses[0], losses


def test_layer_augmentation_adds_echoes_to_the_input_only() -> None:
    from training.train_migrationnet import augment, layer_echoes

    gen = torch.Generator().manual_seed(3)
    assert not layer_echoes(4, ROWS, COLS, gen, 0.0).any()
    layers = layer_echoes(8, ROWS, COLS, gen, 1.0)
    assert all(bool(t.abs().max() > 0.2) for t in layers)
    assert bool((layers.abs() > 0.1).float().mean() < 0.5)  # bands of a wavelet, not a wash over the tile
    xb, yb = torch.zeros(4, 1, ROWS, COLS), torch.zeros(4, 1, ROWS, COLS)
    yb[:, :, 60:70, 60:70] = 1.0
    x_aug, y_aug = augment(xb, yb, torch.Generator().manual_seed(0), layers=1.0)
    assert bool(x_aug.abs().sum() > 0) and torch.equal(y_aug.sum(dim=(1, 2, 3)), yb.sum(dim=(1, 2, 3)))


def test_export_round_trip_and_interpreter(tmp_path: Path) -> None:
    sys.path.insert(0, str(ROOT / "tools"))
    from export_onnx import export

    from training.migrationnet import build_migrationnet

    torch.manual_seed(0)
    model = build_migrationnet(width=2)
    checkpoint = tmp_path / "tiny.pt"
    torch.save({"model": model.state_dict(), "model_config": {"width": 2}, "epoch": 0, "seed": 0,
                "metrics": {}, "data": "none"}, checkpoint)
    card = export("migrationnet", checkpoint, tmp_path / "migrationnet.onnx")
    assert card["parity_max_abs_diff"] < 1e-4 and card["grid"]["rows"] == ROWS
    bscan, gpr = _one_pipe_line()
    section = MigrationNetInterpreter(tmp_path / "migrationnet.onnx", threads=1).interpret(
        bscan, gpr, InterpretationConfig(), velocity_from_eps(EPS_R))
    assert section.mask.shape == (ROWS, len(section.x_m)) == section.image.shape
    assert section.velocity_m_per_ns == pytest.approx(velocity_from_eps(EPS_R))

    card_path = tmp_path / "migrationnet.json"
    card["grid"]["dx_m"] = 0.02
    card_path.write_text(json.dumps(card))
    with pytest.raises(ModelError, match="grid"):
        MigrationNetInterpreter(tmp_path / "migrationnet.onnx")


@pytest.mark.skipif(not SHIPPED.exists(), reason="models/migrationnet.onnx not exported yet")
def test_shipped_model_finds_the_pipe() -> None:
    bscan, gpr = _one_pipe_line()
    section = MigrationNetInterpreter(SHIPPED, threads=2).interpret(
        bscan, gpr, InterpretationConfig(), velocity_from_eps(EPS_R))
    assert len(section.detections) == 1
    d = section.detections[0]
    assert d.x_m == pytest.approx(PIPE_X, abs=0.03) and d.depth_m == pytest.approx(PIPE_DEPTH, abs=0.03)
    assert d.radius_m == pytest.approx(PIPE_RADIUS, abs=0.02)


def test_a_line_read_backwards_gives_the_mirrored_answer() -> None:
    # the network's answers for the line and for it mirrored are averaged: so the mirror is exact
    bscan, gpr = _one_pipe_line()
    image, _ = depth_section(bscan, gpr, velocity_from_eps(EPS_R))
    net = MigrationNetInterpreter(SHIPPED, threads=1)
    forward, backward = net.probabilities(image), net.probabilities(np.ascontiguousarray(image[:, ::-1]))
    np.testing.assert_allclose(backward, forward[:, ::-1], atol=1e-6)
    assert forward.max() > 0.5


def test_training_logs_its_recipe_and_resumes_only_the_same_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import argparse

    from training import train_migrationnet as tm

    rng = np.random.default_rng(0)
    x = rng.normal(size=(4, 1, ROWS, COLS)).astype(np.float16)
    y = (rng.random((4, 1, ROWS, COLS)) < 0.05).astype(np.uint8)
    monkeypatch.setattr(tm, "build_split", lambda split, limit=None: split)
    monkeypatch.setattr(tm, "load_split", lambda split: (x, y))
    monkeypatch.setattr(tm, "CHECKPOINTS", tmp_path / "checkpoints")
    monkeypatch.setattr(tm, "LOGS", tmp_path / "logs")
    args = argparse.Namespace(epochs=1, batch=2, lr=1e-3, width=2, seed=0, threads=1, limit=4, name="tiny",
                              resume=True, layers=0.0, keep_epochs=False, init=None)
    tm.train(args)
    first = json.loads((tmp_path / "logs" / "tiny.jsonl").read_text().splitlines()[0])
    assert first == {"run": tm.recipe(args), "name": "tiny"} and first["run"]["epochs"] == 1
    longer = argparse.Namespace(**(vars(args) | {"epochs": 2}))  # another schedule: not the same run
    with pytest.raises(SystemExit, match="epochs"):
        tm.train(longer)
    tm.train(argparse.Namespace(**(vars(longer) | {"resume": False})))
