"""GPRNet and the PCN / PF-Net baselines: sparse cloud (B, 1500, 3) → dense cloud (B, 8064, 3).

All three take and give clouds normalised to the unit cube and end with the same number of points
(896 seeds × a 3×3 fold = 8064, the paper's count), so the Chamfer distances compare like with like.
`forward` returns the dense cloud (what is exported to ONNX); `forward_stages` returns every stage
(coarse → fine) for the multi-stage training loss.

The "global share" lever: a layer applied to [per-point features, global vector] is split as
W·[p; g] = W_p·p + W_g·g, and W_g·g is computed once per sample and broadcast over the points instead
of tiling g over every point — identical output, far fewer multiply-adds.
"""

from __future__ import annotations

import itertools

import torch
from torch import nn

DEFAULT_GRID_HALF_WIDTH = 0.02  # folding grid half-size in normalised units (~4 cm on a 2 m cube)


def folding_grid(side: int, half_width: float) -> torch.Tensor:
    """A side×side 2-D grid (side², 2) in [-half_width, half_width]²."""
    ticks = torch.linspace(-half_width, half_width, side)
    return torch.tensor(list(itertools.product(ticks.tolist(), ticks.tolist())), dtype=torch.float32)


class GlobalShareLayer(nn.Module):
    """Linear layer on [per-point features (B, N, P); global (B, G)] with the global share computed once."""

    def __init__(self, point_dim: int, global_dim: int, out_dim: int) -> None:
        super().__init__()
        self.point = nn.Linear(point_dim, out_dim)
        self.glob = nn.Linear(global_dim, out_dim, bias=False)

    def forward(self, points: torch.Tensor, global_feature: torch.Tensor) -> torch.Tensor:
        """W_p·p + W_g·g, broadcast over the N points."""
        return self.point(points) + self.glob(global_feature).unsqueeze(1)


class FoldingHead(nn.Module):
    """Folds a 2-D grid around every seed: seed + MLP([global; seed; grid]) for each of the grid points."""

    def __init__(self, global_dim: int, hidden: int, grid_side: int, grid_half_width: float) -> None:
        super().__init__()
        self.register_buffer("grid", folding_grid(grid_side, grid_half_width), persistent=False)
        self.first = GlobalShareLayer(3 + 2, global_dim, hidden)
        self.rest = nn.Sequential(nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 3))

    def forward(self, seeds: torch.Tensor, global_feature: torch.Tensor) -> torch.Tensor:
        """Seeds (B, S, 3) and global (B, G) → (B, S·k, 3), k = grid points per seed."""
        grid: torch.Tensor = self.grid  # type: ignore[assignment]
        b, s, _ = seeds.shape
        k = grid.shape[0]
        centres = seeds.unsqueeze(2).expand(b, s, k, 3).reshape(b, s * k, 3)
        local = torch.cat([centres, grid.unsqueeze(0).expand(s, k, 2).reshape(1, s * k, 2).expand(b, -1, -1)], 2)
        return centres + self.rest(self.first(local, global_feature))


class GPRNet(nn.Module):
    """GPRNet: multi-level PointNet encoder (64/128/256 + fused layer → global) and a multi-branch decoder.

    Decoder: FC branches give 256/128/64 points, an MLP reshapes the global vector into 448 more, together
    896 seeds; a folding head puts 9 points around each seed → 8064.

    `input_seeds` > 0 (our variant, not the paper's): that many input points (a stride of the input, which is
    already a random resample) replace the reshaped-global seeds, each moved by a learned offset from
    [point; global], and the offsets and the fold start at zero — the net starts from a copy of the slices
    and learns to fill between them, which trains in far fewer steps than generating every point.
    """

    def __init__(
        self,
        widths: tuple[int, ...] = (64, 128, 256),
        fuse_hidden: int = 64,
        global_dim: int = 896,
        decoder_hidden: int = 512,
        branch_points: tuple[int, ...] = (256, 128, 64),
        reshape_points: int = 448,
        fold_hidden: int = 128,
        grid_side: int = 3,
        grid_half_width: float = DEFAULT_GRID_HALF_WIDTH,
        input_seeds: int = 0,
        branch_widths: tuple[int, ...] = (),
    ) -> None:
        super().__init__()
        dims = (3, *widths)
        self.input_seeds = input_seeds
        self.reshape_points = reshape_points
        self.levels = nn.ModuleList(nn.Linear(a, b) for a, b in itertools.pairwise(dims))
        # fuse_hidden 0: the paper's single fused PointNet layer [features; pooled] → global_dim; > 0: through
        # a narrower hidden layer first (the CPU-sized variant; EVAL.md says what it costs)
        self.fuse = GlobalShareLayer(sum(widths), sum(widths), fuse_hidden or global_dim)
        self.to_global: nn.Module = nn.Linear(fuse_hidden, global_dim) if fuse_hidden else nn.Identity()
        # branch_widths empty: every branch is one linear layer off a shared decoder_hidden layer; else a chain
        # of FC layers (e.g. 1024/512/256, as in PF-Net's pyramid decoder) with branch i read off layer i
        chain = branch_widths or (decoder_hidden,)
        self.decoder = nn.ModuleList(nn.Linear(a, b) for a, b in itertools.pairwise((global_dim, *chain)))
        taps = branch_widths or (decoder_hidden,) * len(branch_points)
        self.branches = nn.ModuleList(nn.Linear(w, 3 * n) for w, n in zip(taps, branch_points, strict=True))
        self.reshape = nn.Sequential(
            nn.Linear(global_dim, decoder_hidden), nn.ReLU(), nn.Linear(decoder_hidden, 3 * reshape_points)
        )
        self.fold = FoldingHead(global_dim, fold_hidden, grid_side, grid_half_width)
        if input_seeds:
            self.anchor_first = GlobalShareLayer(3, global_dim, fold_hidden)
            self.anchor_out = nn.Linear(fold_hidden, 3)
            for layer in (self.anchor_out, self.fold.rest[-1]):
                nn.init.zeros_(layer.weight)  # type: ignore[arg-type]
                nn.init.zeros_(layer.bias)  # type: ignore[arg-type]

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """(B, N, 3) → global vector (B, global_dim)."""
        features, pooled = [], []
        h = x
        for layer in self.levels:
            h = torch.relu(layer(h))
            features.append(h)
            pooled.append(h.amax(dim=1))
        fused = torch.relu(self.fuse(torch.cat(features, 2), torch.cat(pooled, 1)))
        out: torch.Tensor = self.to_global(fused).amax(dim=1)
        return out

    def forward_stages(self, x: torch.Tensor) -> list[torch.Tensor]:
        """[seeds (B, 896, 3), dense (B, 8064, 3)]."""
        g = self.encode(x)
        levels, h = [], g
        for layer in self.decoder:
            h = torch.relu(layer(h))
            levels.append(h)
        taps = levels if len(levels) == len(self.branches) else levels[-1:] * len(self.branches)
        parts = [branch(t).reshape(x.shape[0], -1, 3) for branch, t in zip(self.branches, taps, strict=True)]
        if self.input_seeds:
            anchors = x[:, :: max(x.shape[1] // self.input_seeds, 1)][:, : self.input_seeds]
            parts.append(anchors + self.anchor_out(torch.relu(self.anchor_first(anchors, g))))
        elif self.reshape_points:
            parts.append(self.reshape(g).reshape(x.shape[0], -1, 3))
        seeds = torch.cat(parts, 1)
        return [seeds, self.fold(seeds, g)]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Sparse (B, N, 3) → dense (B, 8064, 3)."""
        return self.forward_stages(x)[-1]


class PCN(nn.Module):
    """PCN (Yuan et al. 2018): two-stage PointNet encoder, FC coarse cloud, folding refinement."""

    def __init__(
        self,
        first: tuple[int, int] = (128, 256),
        second: tuple[int, int] = (256, 512),
        coarse_points: int = 896,
        decoder_hidden: int = 512,
        fold_hidden: int = 128,
        grid_side: int = 3,
        grid_half_width: float = DEFAULT_GRID_HALF_WIDTH,
    ) -> None:
        super().__init__()
        self.first = nn.Sequential(nn.Linear(3, first[0]), nn.ReLU(), nn.Linear(first[0], first[1]))
        self.second_in = GlobalShareLayer(first[1], first[1], second[0])
        self.second_out = nn.Linear(second[0], second[1])
        self.coarse = nn.Sequential(
            nn.Linear(second[1], decoder_hidden), nn.ReLU(),
            nn.Linear(decoder_hidden, decoder_hidden), nn.ReLU(),
            nn.Linear(decoder_hidden, 3 * coarse_points),
        )  # fmt: skip
        self.fold = FoldingHead(second[1], fold_hidden, grid_side, grid_half_width)

    def forward_stages(self, x: torch.Tensor) -> list[torch.Tensor]:
        """[coarse (B, 896, 3), dense (B, 8064, 3)]."""
        f = self.first(x)
        h = torch.relu(self.second_in(f, f.amax(dim=1)))
        g = self.second_out(h).amax(dim=1)
        coarse = self.coarse(g).reshape(x.shape[0], -1, 3)
        return [coarse, self.fold(coarse, g)]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Sparse (B, N, 3) → dense (B, 8064, 3)."""
        return self.forward_stages(x)[-1]


class CombinedMLP(nn.Module):
    """PF-Net's CMLP: a shared MLP whose last layers' max-pools are concatenated into one feature."""

    def __init__(self, widths: tuple[int, ...], pooled_layers: int = 2) -> None:
        super().__init__()
        dims = (3, *widths)
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in itertools.pairwise(dims))
        self.pooled_layers = pooled_layers

    @property
    def out_dim(self) -> int:
        """Width of the concatenated pooled feature."""
        return sum(layer.out_features for layer in self.layers[-self.pooled_layers :])  # type: ignore[misc]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, N, 3) → (B, out_dim)."""
        pooled = []
        h = x
        for i, layer in enumerate(self.layers):
            h = torch.relu(layer(h))
            if i >= len(self.layers) - self.pooled_layers:
                pooled.append(h.amax(dim=1))
        return torch.cat(pooled, 1)


class PFNet(nn.Module):
    """PF-Net (Huang et al. 2020), predicting the whole cloud: multi-resolution CMLP encoder, pyramid decoder.

    Resolutions are the input and its every-2nd / every-4th points (the input is already a uniform random
    resample, so a stride is a random subset; farthest-point sampling is left out). The pyramid: 112 points
    → ×8 = 896 → ×9 = 8064, each level adding offsets predicted from its own feature level.
    """

    def __init__(
        self,
        widths: tuple[int, ...] = (64, 128, 256),
        strides: tuple[int, ...] = (1, 2, 4),
        latent: int = 512,
        feature_dims: tuple[int, int, int] = (256, 256, 128),
        pyramid: tuple[int, int, int] = (112, 8, 9),
        centre_feature: int = 8,
        centre_hidden: int = 64,
    ) -> None:
        super().__init__()
        self.strides = strides
        self.cmlps = nn.ModuleList(CombinedMLP(widths) for _ in strides)
        self.latent = nn.Linear(sum(c.out_dim for c in self.cmlps), latent)  # type: ignore[misc]
        f1, f2, f3 = feature_dims
        self.f1 = nn.Linear(latent, f1)
        self.f2 = nn.Linear(f1, f2)
        self.f3 = nn.Linear(f2, f3)
        n1, k2, k3 = pyramid
        self.pyramid = pyramid
        self.level1 = nn.Linear(f3, 3 * n1)
        self.level2 = nn.Linear(f2, 3 * n1 * k2)
        self.centre_features = nn.Linear(f1, centre_feature * n1 * k2)
        self.level3 = nn.Sequential(
            nn.Linear(centre_feature + 3, centre_hidden), nn.ReLU(), nn.Linear(centre_hidden, 3 * k3)
        )

    def forward_stages(self, x: torch.Tensor) -> list[torch.Tensor]:
        """[level 1 (B, 112, 3), level 2 (B, 896, 3), dense (B, 8064, 3)]."""
        b = x.shape[0]
        n1, k2, k3 = self.pyramid
        codes = [cmlp(x[:, ::stride]) for cmlp, stride in zip(self.cmlps, self.strides, strict=True)]
        z = torch.relu(self.latent(torch.cat(codes, 1)))
        h1 = torch.relu(self.f1(z))
        h2 = torch.relu(self.f2(h1))
        h3 = torch.relu(self.f3(h2))
        p1 = self.level1(h3).reshape(b, n1, 3)
        p2 = (p1.unsqueeze(2) + self.level2(h2).reshape(b, n1, k2, 3)).reshape(b, n1 * k2, 3)
        local = torch.cat([self.centre_features(h1).reshape(b, n1 * k2, -1), p2], 2)
        p3 = (p2.unsqueeze(2) + self.level3(local).reshape(b, n1 * k2, k3, 3)).reshape(b, n1 * k2 * k3, 3)
        return [p1, p2, p3]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Sparse (B, N, 3) → dense (B, 8064, 3)."""
        return self.forward_stages(x)[-1]


def build_gprnet(**cfg: object) -> GPRNet:
    """GPRNet from keyword config (see GPRNet.__init__)."""
    return GPRNet(**cfg)  # type: ignore[arg-type]


def build_pcn(**cfg: object) -> PCN:
    """PCN baseline from keyword config (see PCN.__init__)."""
    return PCN(**cfg)  # type: ignore[arg-type]


def build_pfnet(**cfg: object) -> PFNet:
    """PF-Net baseline from keyword config (see PFNet.__init__)."""
    return PFNet(**cfg)  # type: ignore[arg-type]


BUILDERS = {"gprnet": build_gprnet, "pcn": build_pcn, "pfnet": build_pfnet}


def parameter_count(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
