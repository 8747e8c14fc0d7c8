"""OnnxModel: a tiny ONNX graph (y = 2x + 1) built with the onnx helper API, and its model card."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from gprbot.errors import ModelError
from gprbot.infer.onnx_model import OnnxModel, file_sha256


def _write_model(folder: Path, name: str = "affine") -> Path:
    """An ONNX model y = 2x + 1 on x (batch, 3) float32, and its card beside it."""
    two = helper.make_tensor("two", TensorProto.FLOAT, [], [2.0])
    one = helper.make_tensor("one", TensorProto.FLOAT, [], [1.0])
    graph = helper.make_graph(
        [helper.make_node("Mul", ["x", "two"], ["doubled"]), helper.make_node("Add", ["doubled", "one"], ["y"])],
        "affine",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["batch", 3])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["batch", 3])],
        initializer=[two, one],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 9
    onnx.checker.check_model(model)
    path = folder / f"{name}.onnx"
    onnx.save(model, str(path))
    card = {
        "name": name,
        "sha256": file_sha256(path),
        "inputs": [{"name": "x", "shape": ["batch", 3], "dtype": "float32", "units": "mV"}],
        "outputs": [{"name": "y", "shape": ["batch", 3], "dtype": "float32", "units": "mV"}],
    }
    path.with_suffix(".json").write_text(json.dumps(card))
    return path


def _edit_card(path: Path, **changes: object) -> None:
    card_path = path.with_suffix(".json")
    card = json.loads(card_path.read_text())
    card.update(changes)
    card_path.write_text(json.dumps(card))


def test_runs_the_graph_and_times_it(tmp_path: Path) -> None:
    model = OnnxModel(_write_model(tmp_path), threads=1, expect_name="affine")
    x = np.array([[0.0, 1.0, -2.5], [3.0, 4.0, 5.0]], dtype=np.float32)
    outputs, seconds = model.run({"x": x})
    np.testing.assert_allclose(outputs["y"], 2.0 * x + 1.0)
    assert seconds >= 0.0 and model.warmup_s >= 0.0
    assert [s.name for s in model.inputs] == ["x"] and model.inputs[0].shape == ("batch", 3)


@pytest.mark.parametrize(
    ("inputs", "message"),
    [
        ({"x": np.zeros((2, 3), np.float64)}, "must be float32"),
        ({"x": np.zeros((2, 4), np.float32)}, "must have shape"),
        ({"x": np.zeros(3, np.float32)}, "must have shape"),
        ({"z": np.zeros((2, 3), np.float32)}, "the model takes"),
    ],
)
def test_wrong_inputs_are_refused_with_what_is_expected(tmp_path: Path, inputs: dict[str, np.ndarray],
                                                        message: str) -> None:
    model = OnnxModel(_write_model(tmp_path), threads=1)
    with pytest.raises(ModelError, match=message):
        model.run(inputs)


def test_missing_model_says_how_to_get_one(tmp_path: Path) -> None:
    with pytest.raises(ModelError, match=r"export_onnx\.py"):
        OnnxModel(tmp_path / "absent.onnx")


def test_missing_card_is_refused(tmp_path: Path) -> None:
    path = _write_model(tmp_path)
    path.with_suffix(".json").unlink()
    with pytest.raises(ModelError, match=r"card .* is missing"):
        OnnxModel(path)


def test_a_changed_model_file_fails_the_checksum(tmp_path: Path) -> None:
    path = _write_model(tmp_path)
    path.write_bytes(path.read_bytes() + b"\0")
    with pytest.raises(ModelError, match=r"sha256"):
        OnnxModel(path)


def test_a_corrupt_model_whose_card_matches_is_refused_by_the_runtime(tmp_path: Path) -> None:
    path = _write_model(tmp_path)
    path.write_bytes(path.read_bytes()[:40])
    _edit_card(path, sha256=file_sha256(path))
    with pytest.raises(ModelError, match="onnxruntime cannot load"):
        OnnxModel(path)


def test_card_that_disagrees_with_the_graph_is_refused(tmp_path: Path) -> None:
    path = _write_model(tmp_path)
    _edit_card(path, inputs=[{"name": "x", "shape": ["batch", 4], "dtype": "float32"}])
    with pytest.raises(ModelError, match="in the card"):
        OnnxModel(path)
    _edit_card(path, inputs=[{"name": "x", "shape": ["batch", 3], "dtype": "float32"}],
               outputs=[{"name": "probability", "shape": ["batch", 3], "dtype": "float32"}])
    with pytest.raises(ModelError, match="differ from the model"):
        OnnxModel(path)


def test_wrong_model_name_and_unreadable_card(tmp_path: Path) -> None:
    path = _write_model(tmp_path)
    with pytest.raises(ModelError, match="expected 'migrationnet'"):
        OnnxModel(path, expect_name="migrationnet")
    path.with_suffix(".json").write_text("{not json")
    with pytest.raises(ModelError, match="cannot be read"):
        OnnxModel(path)


def test_card_named_after_the_full_file_name_takes_precedence(tmp_path: Path) -> None:
    path = _write_model(tmp_path)
    card = json.loads(path.with_suffix(".json").read_text())
    path.with_name(path.name + ".json").write_text(json.dumps({**card, "name": "other"}))
    assert OnnxModel(path).name == "other"
