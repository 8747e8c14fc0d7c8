"""Chamfer distances and F-score against hand-computed values and a brute-force reference."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from training.chamfer import chamfer_l1, chamfer_l2, cloud_metrics  # noqa: E402


def brute_force(pred: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """CD2 and CD1 from the full distance matrix (DESIGN §6)."""
    d = np.sqrt(((pred[:, None, :] - truth[None, :, :]) ** 2).sum(-1))
    a, b = d.min(axis=1), d.min(axis=0)
    return float(np.mean(a**2) + np.mean(b**2)), float(0.5 * (np.mean(a) + np.mean(b)))


def test_two_single_points_give_the_textbook_values() -> None:
    pred, truth = np.array([[0.0, 0.0, 0.0]]), np.array([[0.3, 0.4, 0.0]])  # 0.5 apart
    m = cloud_metrics(pred, truth, threshold=0.01)
    assert m.cd2 == pytest.approx(2 * 0.25)
    assert m.cd1 == pytest.approx(0.5)
    assert m.fscore == 0.0


def test_numpy_and_torch_match_brute_force_on_random_clouds() -> None:
    rng = np.random.default_rng(3)
    pred, truth = rng.random((300, 3)), rng.random((200, 3))
    cd2, cd1 = brute_force(pred, truth)
    m = cloud_metrics(pred, truth)
    assert m.cd2 == pytest.approx(cd2, rel=1e-9)
    assert m.cd1 == pytest.approx(cd1, rel=1e-9)
    p, t = torch.tensor(pred[None]), torch.tensor(truth[None])
    assert float(chamfer_l2(p, t)[0]) == pytest.approx(cd2, rel=1e-9)
    assert float(chamfer_l1(p, t, eps=0.0)[0]) == pytest.approx(cd1, rel=1e-9)


def test_fscore_counts_points_within_the_threshold() -> None:
    truth = np.random.default_rng(0).random((500, 3)) * 10.0  # sparse enough that only the twin is near
    assert cloud_metrics(truth + np.array([0.004, 0.0, 0.0]), truth, threshold=0.01).fscore == pytest.approx(1.0)
    assert cloud_metrics(truth + np.array([0.02, 0.0, 0.0]), truth, threshold=0.01).fscore == pytest.approx(0.0)
    half = truth.copy()
    half[:250] += [0.02, 0.0, 0.0]  # precision 0.5, recall 0.5
    assert cloud_metrics(half, truth, threshold=0.01).fscore == pytest.approx(0.5)


def test_gradient_is_the_analytic_one_and_finite_at_coincident_points() -> None:
    p = torch.tensor([[[0.1, 0.2, 0.3]]], dtype=torch.float64, requires_grad=True)
    q = torch.tensor([[[0.4, 0.2, -0.1]]], dtype=torch.float64)
    chamfer_l2(p, q).sum().backward()
    # both directions pair p with q: d/dp (2 |p - q|²) = 4 (p - q)
    assert torch.allclose(p.grad, 4.0 * (p.detach() - q))
    same = torch.zeros(1, 5, 3, requires_grad=True)
    chamfer_l1(same, torch.zeros(1, 5, 3)).sum().backward()
    chamfer_l2(same, torch.zeros(1, 5, 3)).sum().backward()
    assert torch.all(torch.isfinite(same.grad))


def test_empty_cloud_is_refused() -> None:
    with pytest.raises(ValueError, match="non-empty"):
        cloud_metrics(np.zeros((0, 3)), np.zeros((4, 3)))
