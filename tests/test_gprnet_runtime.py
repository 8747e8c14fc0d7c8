"""GPRNet at run time (ONNX, normalisation round trip, pipes + dense cloud) and a short training smoke run."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

from gprbot.config import ReconstructionConfig  # noqa: E402
from gprbot.errors import InterpretationError, ModelError  # noqa: E402
from gprbot.infer.gprnet import GprnetCompletion, gprnet_reconstruction, normalisation  # noqa: E402
from gprbot.infer.onnx_model import file_sha256  # noqa: E402
from gprbot.reconstruct.register import register_slice  # noqa: E402
from training import train_completion  # noqa: E402
from training.pointcloud_models import build_gprnet  # noqa: E402

TINY = {"widths": (16, 16, 32), "fuse_hidden": 16, "global_dim": 32, "decoder_hidden": 32, "fold_hidden": 16}


def export_with_card(model: torch.nn.Module, path: Path) -> None:
    """ONNX export plus the model card OnnxModel checks (the format tools/export_onnx.py writes)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter announces its deprecation
        torch.onnx.export(model.eval(), (torch.zeros(1, 1500, 3),), str(path), input_names=["sparse_points"],
                          output_names=["dense_points"], dynamo=False, opset_version=17)
    card = {"name": "gprnet", "sha256": file_sha256(path),
            "inputs": [{"name": "sparse_points", "shape": ["batch", 1500, 3], "dtype": "float32"}],
            "outputs": [{"name": "dense_points", "shape": ["batch", 8064, 3], "dtype": "float32"}]}
    path.with_suffix(".json").write_text(json.dumps(card))


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory: pytest.TempPathFactory) -> tuple[torch.nn.Module, Path]:
    torch.manual_seed(0)
    model = build_gprnet(**TINY).eval()
    path = tmp_path_factory.mktemp("models") / "gprnet.onnx"
    export_with_card(model, path)
    return model, path


def pipe_slices(lines: int = 6) -> list:
    """Slices of one straight pipe (r = 5 cm, axis 0.3 m deep) crossing lines along x at x = 1 m."""
    z = np.arange(0.0, 0.6, 0.005)
    x = np.arange(0.0, 2.0, 0.005)
    slices = []
    for line in range(lines):
        columns = np.column_stack([x, np.full(len(x), 0.1 * line), np.zeros(len(x))])
        mask = (x[None, :] - 1.0) ** 2 + (z[:, None] - 0.3) ** 2 <= 0.05**2
        slices.append(register_slice(line, mask, z, columns))
    return slices


def test_normalisation_maps_the_bounding_box_into_the_unit_cube() -> None:
    cloud = np.random.default_rng(1).random((1500, 3)) * [2.0, 0.5, 0.3] + [5.0, -1.0, -0.6]
    centre, scale = normalisation(cloud)
    unit = (cloud - centre) / scale
    assert float(np.ptp(unit, axis=0).max()) == pytest.approx(1.0)
    assert np.allclose(unit.min(axis=0), -unit.max(axis=0))


def test_complete_equals_the_torch_model_in_metres(tiny_model: tuple[torch.nn.Module, Path]) -> None:
    model, path = tiny_model
    completion = GprnetCompletion(path, threads=1)
    sparse = np.random.default_rng(2).random((1500, 3)) * [2.0, 0.5, 0.2] + [10.0, 3.0, -0.5]
    dense = completion.complete(sparse)
    centre, scale = 0.5 * (sparse.min(0) + sparse.max(0)), float(np.ptp(sparse, axis=0).max())
    with torch.no_grad():
        expected = model(torch.tensor((sparse - centre) / scale, dtype=torch.float32)[None])[0].numpy()
    assert dense.shape == (8064, 3)
    assert np.allclose(dense, expected * scale + centre, atol=1e-4)
    assert completion.last_seconds > 0.0


def test_bad_inputs_and_missing_models_are_refused(tiny_model: tuple[torch.nn.Module, Path], tmp_path: Path) -> None:
    completion = GprnetCompletion(tiny_model[1], threads=1)
    with pytest.raises(InterpretationError, match="1500"):
        completion.complete(np.zeros((10, 3)))
    with pytest.raises(ModelError):
        GprnetCompletion(tmp_path / "absent.onnx")


def test_reconstruction_takes_pipes_from_the_fit_and_the_cloud_from_the_model(
    tiny_model: tuple[torch.nn.Module, Path],
) -> None:
    slices = pipe_slices()
    sparse = np.concatenate([s.points for s in slices])
    rng = np.random.default_rng(3)
    recon = gprnet_reconstruction(slices, sparse, ReconstructionConfig(), GprnetCompletion(tiny_model[1]), rng)
    assert len(recon.pipes) == 1
    pipe = recon.pipes[0]
    assert pipe.diameter_m == pytest.approx(0.1, abs=0.02)
    assert pipe.depth_of_cover_m == pytest.approx(0.25, abs=0.02)
    assert recon.dense.shape == (8064, 3) and np.all(recon.labels == 0)


def test_a_few_training_steps_reduce_the_loss_and_resume(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Smoke run of the real training loop on a tiny synthetic set: a pipe-like rod, killed, resumed, refused."""
    rng = np.random.default_rng(4)
    t = rng.random((16, 8192, 1)) - 0.5
    dense = np.concatenate([0.05 * rng.standard_normal((16, 8192, 1)), t, 0.05 * rng.standard_normal((16, 8192, 1))],
                           axis=2).astype(np.float32)
    sparse = dense[:, :1500].copy()
    dense[5] *= 40.0  # a truth far outside its sparse cloud's cube: left out, or its loss swamps the rest
    arrays = {"sparse": sparse, "dense": dense, "seed": np.arange(100, 116)}
    monkeypatch.setattr(train_completion, "load_split", lambda split: arrays)
    monkeypatch.setattr(train_completion, "CHECKPOINTS", tmp_path / "ckpt")
    monkeypatch.setattr(train_completion, "LOGS", tmp_path / "logs")
    monkeypatch.setattr(train_completion, "MODEL_CONFIGS", {"gprnet": TINY})
    common = ["--model", "gprnet", "--batch-size", "4", "--loss-points", "512", "--val-limit", "4", "--lr", "3e-3"]
    # A run killed after its second epoch's checkpoint (the third validation never returns) ...
    real_validate, calls = train_completion.validate, []

    def validate_then_die(*args: object) -> dict[str, float]:
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt("killed")
        return real_validate(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(train_completion, "validate", validate_then_die)
    with pytest.raises(KeyboardInterrupt):
        train_completion.train(train_completion.parse_args([*common, "--epochs", "3"]))
    monkeypatch.setattr(train_completion, "validate", real_validate)
    # ... resumes where it stopped when the same command runs again, and ends where one unbroken run ends
    resumed = train_completion.train(train_completion.parse_args([*common, "--epochs", "3"]))
    history = resumed["history"]
    assert [h["epoch"] for h in history] == [1, 2, 3]
    assert history[-1]["train_loss"] < 0.7 * history[0]["train_loss"]
    # another budget is another schedule: refused, not spliced onto this one
    with pytest.raises(SystemExit, match="--fresh"):
        train_completion.train(train_completion.parse_args([*common, "--epochs", "4"]))
    best = torch.load(tmp_path / "ckpt" / "gprnet" / "best.pt", weights_only=False)
    assert best["model_config"] == TINY and "optimizer" not in best
    assert best["data"]["left_out_seeds"] == [105] and best["data"]["train"] == 15
