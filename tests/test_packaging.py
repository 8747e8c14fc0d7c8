"""The wheel holds what an installed gprbot needs: the models the shipped configs name, one version."""

from __future__ import annotations

import ast
import tomllib
from importlib import resources
from pathlib import Path

import gprbot
from gprbot.config import load_config

REPO = Path(__file__).resolve().parents[1]


def _shipped_models() -> tuple[str, ...]:
    tree = ast.parse((REPO / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "SHIPPED_MODELS":
            return tuple(ast.literal_eval(node.value))
    raise AssertionError("setup.py has no SHIPPED_MODELS")


def test_every_model_a_shipped_config_names_goes_into_the_wheel_and_the_sdist() -> None:
    manifest = (REPO / "MANIFEST.in").read_text()
    names = resources.files("gprbot").joinpath("configs").iterdir()
    for config in (f.name.removesuffix(".yaml") for f in names if f.name.endswith(".yaml")):
        cfg = load_config(config)
        for path in (cfg.interpretation.migrationnet_model, cfg.reconstruction.gprnet_model):
            stem = Path(path).stem
            assert stem in _shipped_models(), f"{config}: {path} is not copied into the wheel (setup.py)"
            for suffix in (".onnx", ".json"):
                assert f"models/{stem}{suffix}" in manifest, f"{stem}{suffix} is not in MANIFEST.in"
                assert (REPO / "models" / f"{stem}{suffix}").is_file()


def test_one_version_source_and_a_viewer_install_without_the_realsense_sdk() -> None:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert "version" not in project and project["dynamic"] == ["version"]
    assert gprbot.__version__.count(".") == 2
    assert not any("pyrealsense2" in dep for dep in project["dependencies"])
    assert any(dep.startswith("pyrealsense2") for dep in project["optional-dependencies"]["robot"])
    assert (REPO / "LICENSE").read_text().lstrip().startswith("Apache License")
