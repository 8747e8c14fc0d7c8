"""The code version that keys the evaluation caches: the sources a result comes from, and files named."""

from __future__ import annotations

from pathlib import Path

from training.code_version import ROOT, code_version, source_closure


def test_the_closure_follows_imports_through_modules_and_functions() -> None:
    files = {p.relative_to(ROOT).as_posix() for p in source_closure(["training.evaluate"])}
    # the data generator, the scoring, the models' definitions and what they import in turn
    assert {"training/evaluate.py", "training/pointcloud_data.py", "training/chamfer.py",
            "training/pointcloud_models.py", "gprbot/sim/truth.py", "gprbot/reconstruct/completion.py",
            "training/__init__.py", "gprbot/__init__.py"} <= files
    assert "training/eval_end_to_end.py" not in files and "gprbot/daemon.py" not in files
    # scenes.py imports gprmax_input inside a function (a cycle at import time)
    lazy = {p.name for p in source_closure(["validation.fdtd.scenes"])}
    assert "gprmax_input.py" in lazy


def test_the_version_changes_with_a_named_file(tmp_path: Path) -> None:
    model = tmp_path / "model.onnx"
    model.write_bytes(b"weights v1")
    first = code_version(["training.chamfer"], [model])
    assert code_version(["training.chamfer"], [model]) == first
    model.write_bytes(b"weights v2")
    assert code_version(["training.chamfer"], [model]) != first
    assert code_version(["training.evaluate"], [model]) != code_version(["training.chamfer"], [model])
