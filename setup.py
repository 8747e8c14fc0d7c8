"""Packaging hook: the models the shipped configs name go into the wheel as gprbot/models (package data).

The checkout keeps models/ at the top (the product's layout); an installed gprbot finds them through
gprbot.config.model_path, which looks in the checkout first and in gprbot/models second.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

# The models the shipped configs can select (interpretation.method, reconstruction.completion); the completion
# baselines (pcn, pfnet, the GPRNet ablation) are for training/evaluate in a checkout and stay out of the wheel.
SHIPPED_MODELS = ("migrationnet", "gprnet", "fit_refiner")


class BuildWithModels(build_py):
    """build_py that also copies models/<name>.onnx and its card into the built gprbot package."""

    def run(self) -> None:
        super().run()
        source = Path(__file__).resolve().parent / "models"
        target = Path(self.build_lib) / "gprbot" / "models"
        target.mkdir(parents=True, exist_ok=True)
        for name in SHIPPED_MODELS:
            for suffix in (".onnx", ".json"):
                path = source / f"{name}{suffix}"
                if not path.is_file():
                    raise FileNotFoundError(f"{path} is missing: without it the learned config cannot run")
                shutil.copy2(path, target / path.name)


setup(cmdclass={"build_py": BuildWithModels})
