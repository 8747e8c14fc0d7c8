"""MigrationNet's FDTD fine-tune: ONNX models back in PyTorch exactly, true pipe masks, folds of the dev half."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("onnx")

from gprbot.config import GprConfig
from gprbot.gpr.bscan import BScan
from gprbot.infer.migrationnet import DX_M, DZ_M, depth_grid
from training.finetune_fdtd import dev_folds, pipe_mask, true_depths
from training.onnx_weights import check_parity, migrationnet_from_onnx
from validation.cases import Case
from validation.scoring import Target

MODELS = (Path(__file__).resolve().parents[1] / "models" / "migrationnet.onnx",
          Path(__file__).resolve().parents[1] / "training" / "base" / "migrationnet_sim.onnx")


@pytest.mark.parametrize("path", MODELS, ids=("shipped", "base"))
def test_an_onnx_model_comes_back_into_pytorch_unchanged(path: Path) -> None:
    model = migrationnet_from_onnx(path)
    assert check_parity(model, path) < 1e-4


def test_a_model_of_another_width_is_refused() -> None:
    with pytest.raises(ValueError, match="shape"):
        migrationnet_from_onnx(MODELS[0], width=4)


def _case(*targets: Target) -> Case:
    def load() -> tuple[BScan, GprConfig]:
        raise AssertionError("not loaded")
    return Case("t", "fdtd-dev", load, 0.1, targets, 0.03)


def test_the_pipe_mask_is_the_true_disc_and_rebars_stay_background() -> None:
    x = np.arange(100) * DX_M
    mask = pipe_mask(_case(Target(0.40, 0.20, 0.05, "pipe"), Target(0.70, 0.10, 0.01, "rebar")), x)
    z = depth_grid()
    row, col = int(np.argmin(abs(z - 0.20))), 40
    assert mask[row, col]
    assert mask[row, col + 4] and not mask[row, col + 6]  # 5 cm either side at 1 cm columns
    assert mask[int(np.argmin(abs(z - 0.16))), col] and not mask[int(np.argmin(abs(z - 0.26))), col]
    assert not mask[:, 65:].any()  # the rebar is not a pipe
    assert abs(mask.sum() * DX_M * DZ_M - np.pi * 0.05**2) < 0.15 * np.pi * 0.05**2


def test_a_section_converted_too_fast_shows_the_pipe_deeper_and_the_mask_follows() -> None:
    gpr = GprConfig()
    z = depth_grid()
    assert np.allclose(true_depths(z, 0.1, 1.0, gpr), z, atol=2e-4)
    deeper = true_depths(z, 0.1, 1.06, gpr)
    assert np.all(deeper[20:] < z[20:])  # a row of the fast section holds a shallower true depth
    x = np.arange(60) * DX_M
    case = _case(Target(0.30, 0.20, 0.03, "pipe"))
    rows_true = np.flatnonzero(pipe_mask(case, x)[:, 30])
    rows_fast = np.flatnonzero(pipe_mask(case, x, deeper)[:, 30])
    assert rows_fast.mean() > rows_true.mean() + 1.5  # about 6 % of 0.2 m = 2.6 rows deeper


def test_a_pipe_thinner_than_a_pixel_still_marks_its_centre() -> None:
    x = np.arange(50) * DX_M
    mask = pipe_mask(_case(Target(0.203, 0.10, 0.002, "pipe")), x)
    assert mask.any() and mask[:, 20].any()


def test_the_folds_split_the_dev_half_and_never_hold_a_test_scene() -> None:
    a, b = dev_folds()
    names_a, names_b = {c.name for c in a}, {c.name for c in b}
    assert not names_a & names_b
    assert all(c.group == "fdtd-dev" for c in a + b)
    assert abs(len(a) - len(b)) <= 1 and len(a) + len(b) >= 30
