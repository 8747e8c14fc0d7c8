"""GPRNet, PCN and PF-Net: output sizes, the global-share lever, order invariance, the dataset samples."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from training.chamfer import cloud_metrics  # noqa: E402
from training.pointcloud_models import (  # noqa: E402
    BUILDERS,
    GlobalShareLayer,
    build_gprnet,
    build_pcn,
    folding_grid,
)


@pytest.mark.parametrize("name", sorted(BUILDERS))
def test_every_model_maps_1500_points_to_8064(name: str) -> None:
    torch.manual_seed(0)
    model = BUILDERS[name]().eval()
    with torch.no_grad():
        stages = model.forward_stages(torch.rand(2, 1500, 3) - 0.5)
        dense = model(torch.rand(2, 1500, 3) - 0.5)
    assert dense.shape == (2, 8064, 3)
    assert stages[-1].shape == (2, 8064, 3)
    assert [s.shape[1] for s in stages[:-1]][-1] == 896  # the seeds folded 3×3 into 8064


def test_global_share_layer_equals_a_linear_layer_on_the_tiled_concatenation() -> None:
    torch.manual_seed(1)
    layer = GlobalShareLayer(5, 7, 4)
    full = torch.nn.Linear(12, 4)
    with torch.no_grad():
        full.weight.copy_(torch.cat([layer.point.weight, layer.glob.weight], 1))
        full.bias.copy_(layer.point.bias)
    points, glob = torch.rand(3, 11, 5), torch.rand(3, 7)
    tiled = torch.cat([points, glob[:, None, :].expand(-1, 11, -1)], 2)
    assert torch.allclose(layer(points, glob), full(tiled), atol=1e-6)


@pytest.mark.parametrize("builder", [build_gprnet, build_pcn])
def test_pointnet_encoders_ignore_the_order_of_the_input_points(builder: object) -> None:
    torch.manual_seed(2)
    model = builder(global_dim=32, decoder_hidden=16, fold_hidden=8) if builder is build_gprnet else builder()  # type: ignore[operator]
    x = torch.rand(1, 1500, 3)
    with torch.no_grad():
        assert torch.allclose(model(x), model(x[:, torch.randperm(1500)]), atol=1e-5)


def test_full_width_fuse_is_one_pointnet_layer_straight_to_the_global_vector() -> None:
    torch.manual_seed(3)
    model = build_gprnet(fuse_hidden=0, global_dim=32, decoder_hidden=16, fold_hidden=8).eval()
    assert isinstance(model.to_global, torch.nn.Identity) and model.fuse.point.out_features == 32
    x = torch.rand(1, 1500, 3)
    with torch.no_grad():
        assert model.encode(x).shape == (1, 32)
        assert torch.allclose(model(x), model(x[:, torch.randperm(1500)]), atol=1e-5)


def test_folding_grid_spans_the_requested_square() -> None:
    grid = folding_grid(3, 0.02)
    assert grid.shape == (9, 2)
    assert float(grid.min()) == pytest.approx(-0.02) and float(grid.max()) == pytest.approx(0.02)
    assert len({tuple(row) for row in grid.tolist()}) == 9


def test_dataset_sample_is_normalised_and_its_truth_lies_along_the_slices() -> None:
    from training.pointcloud_data import DENSE_POINTS, SPARSE_POINTS, make_sample

    sample = make_sample(0)  # seed 0 is the "straight" case
    assert sample is not None and sample.case == "straight"
    assert sample.sparse.shape == (SPARSE_POINTS, 3) and sample.dense.shape == (DENSE_POINTS, 3)
    extent = sample.sparse.max(axis=0) - sample.sparse.min(axis=0)
    assert float(extent.max()) == pytest.approx(1.0, abs=1e-6)
    assert np.allclose(sample.sparse.max(axis=0) + sample.sparse.min(axis=0), 0.0, atol=1e-6)
    # the slices are sections of the true pipe: most sparse points lie within a few mm of the truth
    near = cloud_metrics(sample.sparse, sample.dense)
    assert near.cd1 * sample.scale < 0.05


def test_split_made_in_worker_processes_equals_the_one_made_in_one() -> None:
    from training.pointcloud_data import build_split

    serial, parallel = build_split("val", limit=3), build_split("val", limit=3, jobs=2)
    assert serial.keys() == parallel.keys()
    assert all(np.array_equal(serial[key], parallel[key]) for key in serial)


def test_anchored_gprnet_starts_as_a_copy_of_its_input_seeds() -> None:
    torch.manual_seed(3)
    model = build_gprnet(input_seeds=448, global_dim=32, decoder_hidden=16, fold_hidden=8)
    x = torch.rand(1, 1500, 3)
    with torch.no_grad():
        seeds, dense = model.forward_stages(x)
    anchors = x[:, ::3][:, :448]  # every 3rd input point: the stride 1500 // 448
    assert torch.equal(seeds[:, 448:], anchors)
    assert torch.equal(dense.reshape(1, 896, 9, 3)[:, 448:], anchors[:, :, None, :].expand(-1, -1, 9, -1))


def test_pyramid_branches_read_their_point_sets_off_successive_decoder_layers() -> None:
    torch.manual_seed(4)
    model = build_gprnet(fuse_hidden=0, global_dim=32, branch_widths=(24, 16, 8), fold_hidden=8).eval()
    assert [layer.out_features for layer in model.decoder] == [24, 16, 8]
    assert [(b.in_features, b.out_features) for b in model.branches] == [(24, 768), (16, 384), (8, 192)]
    x = torch.rand(2, 1500, 3)
    with torch.no_grad():
        seeds, dense = model.forward_stages(x)
        model.branches[2].bias.add_(1.0)  # only the last branch's 64 points move
        moved, _ = model.forward_stages(x)
    assert seeds.shape == (2, 896, 3) and dense.shape == (2, 8064, 3)
    changed = (moved != seeds).any(dim=2)[0]
    assert bool(changed[384:448].all()) and not bool(changed[:384].any()) and not bool(changed[448:].any())
