"""The refined completion's decisions (which points and pipes stay) and the shipped FitRefiner end to end."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gprbot.config import ReconstructionConfig
from gprbot.errors import ModelError
from gprbot.infer.refine import FitRefinerModel, accepted, onehot, refined_reconstruction
from gprbot.reconstruct.completion import fit_pipes
from gprbot.reconstruct.register import resample_cloud
from training.random_scenes import scene_for_seed
from training.refine_data import interpreted_slices

MODEL = Path(__file__).resolve().parents[1] / "models" / "fit_refiner.onnx"


def test_a_pipe_whose_fitted_part_is_mostly_rejected_is_dropped_and_its_extension_with_it() -> None:
    owner = np.array([0, 0, 0, 0, 1, 1, 1, 1])
    beyond = np.array([0.0, 0.0, 0.2, 0.3, 0.0, 0.0, 0.1, 0.1])
    probability = np.array([0.9, 0.8, 0.7, 0.2, 0.1, 0.3, 0.9, 0.9])
    points, kept = accepted(probability, owner, beyond, 2)
    assert kept == [0]
    assert points.tolist() == [True, True, True, False, False, False, False, False]


def test_the_likeliest_pipe_stays_when_every_pipe_is_rejected() -> None:
    owner = np.array([0, 0, 1, 1])
    beyond = np.zeros(4)
    points, kept = accepted(np.array([0.1, 0.2, 0.4, 0.3]), owner, beyond, 2)
    assert kept == [1] and points.tolist() == [False, False, True, True]


def test_a_pipe_scoring_under_the_models_pipe_threshold_is_dropped_though_most_of_it_is_accepted() -> None:
    owner = np.array([0, 0, 1, 1])
    beyond = np.zeros(4)
    probability = np.array([0.95, 0.9, 0.8, 0.7])  # pipe 1 scores 0.75: accepted by points, false by the model
    assert accepted(probability, owner, beyond, 2)[1] == [0, 1]
    points, kept = accepted(probability, owner, beyond, 2, pipe_threshold=0.8)
    assert kept == [0] and points.tolist() == [True, True, False, False]


def test_the_pipe_threshold_is_chosen_for_the_most_false_pipes_net_of_the_true_ones_lost() -> None:
    from training.refine_pipe_threshold import LOST_TRUE_COST, choose

    false = np.array([0.70, 0.76, 0.78, 0.93])
    true = np.array([0.77, 0.90, 0.95, 0.96])
    t, dropped_false, dropped_true = choose(false, true)
    # 0.765 drops two false and no true pipe; 0.785 would drop a third false pipe for a true one (cost 2)
    assert LOST_TRUE_COST == 2.0 and (dropped_false, dropped_true) == (2, 0) and 0.76 < t <= 0.77


@pytest.mark.skipif(not MODEL.exists(), reason="models/fit_refiner.onnx not trained yet")
def test_the_refiner_reads_its_pipe_threshold_from_its_card() -> None:
    import json

    card = json.loads(MODEL.with_suffix(".json").read_text())
    assert FitRefinerModel(MODEL, threads=1).pipe_threshold == card.get("pipe_threshold", 0.5)


def test_pipes_beyond_the_one_hot_columns_see_no_pipe_feature() -> None:
    hot = onehot(np.array([0, 2, 14]), n_columns=12)
    assert hot.shape == (3, 12) and hot[0, 0] == 1 and hot[1, 2] == 1 and not hot[2].any()


@pytest.mark.skipif(not MODEL.exists(), reason="models/fit_refiner.onnx not trained yet")
def test_the_shipped_refiner_keeps_fitted_pipes_and_gives_a_full_dense_cloud() -> None:
    from gprbot.config import load_config

    scene, spec = scene_for_seed(200003)  # a test-split tee, not a training scene
    rng = np.random.default_rng(0)
    slices, footprint = interpreted_slices(scene, spec, "migrationnet", rng, load_config())
    cfg = ReconstructionConfig()
    sparse = resample_cloud(np.concatenate([s.points for s in slices]), 1500, rng)
    fitted = fit_pipes(slices, cfg)
    recon = refined_reconstruction(slices, sparse, footprint, cfg, FitRefinerModel(MODEL, threads=1), rng)
    assert 1 <= len(recon.pipes) <= len(fitted)
    assert recon.dense.shape == (cfg.dense_points, 3) and np.all(np.isfinite(recon.dense))
    assert set(np.unique(recon.labels)) <= set(range(len(recon.pipes)))
    xmin, xmax, ymin, ymax = footprint
    slack = 0.06  # MAX_OFFSET of the unit cube, a few cm on this survey
    assert np.all((recon.dense[:, 0] >= xmin - slack) & (recon.dense[:, 0] <= xmax + slack))
    assert np.all((recon.dense[:, 1] >= ymin - slack) & (recon.dense[:, 1] <= ymax + slack))
    for pipe in recon.pipes:
        assert 0.0 <= pipe.confidence <= 1.0 and len(pipe.axis) >= 2


def test_a_model_that_is_not_a_refiner_is_refused_with_what_to_do() -> None:
    other = MODEL.parent / "gprnet.onnx"
    if not other.exists():
        pytest.skip("models/gprnet.onnx not committed")
    with pytest.raises(ModelError, match="fit_refiner"):
        FitRefinerModel(other, threads=1)


def test_the_acceptance_loss_weights_candidates_outside_every_pipe() -> None:
    import torch

    from training.train_refine import accept_loss

    logits, inside = torch.tensor([2.0, 2.0]), torch.tensor([1.0, 0.0])
    each = torch.nn.functional.binary_cross_entropy_with_logits(logits, inside, reduction="none")
    assert float(accept_loss(logits, inside)) == pytest.approx(float(each.mean()))
    assert float(accept_loss(logits, inside, 10.0)) == pytest.approx(float((each[0] + 10.0 * each[1]) / 2.0))


def test_the_into_truth_offset_loss_only_pulls_points_into_the_truth() -> None:
    import torch

    from training.train_refine import refine_loss

    truth = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]])
    moved = torch.tensor([[[0.1, 0.0, 0.0], [5.0, 0.0, 0.0]]])  # the far one is not kept
    keep = torch.tensor([[True, False]])
    one_way = float(refine_loss(moved, keep, truth, both_ways=False))
    assert one_way == pytest.approx(1e3 * 0.01)  # the kept point's distance to the truth, nothing else
    # both ways adds the truth point at x = 1 that no kept point covers: (1 - 0.1)^2, averaged over the truth
    assert float(refine_loss(moved, keep, truth)) == pytest.approx(1e3 * (0.01 + (0.01 + 0.81) / 2.0))
