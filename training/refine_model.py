"""FitRefiner: the fit's rods + the sparse slices → which candidate rod points are real, and their corrections.

The geometric fit is right about most pipes and wrong in ways a network can see: it stops where the
lines stopped seeing a pipe (the pipe goes on), it keeps a false pipe where rebar or clutter made a
section, its radius and depth carry the interpreter's bias. So the network does not generate a cloud
from nothing (GPRNet's task, which it loses to the fit on this CPU budget); it judges the fit's rods,
continued to the survey's edge (gprbot.reconstruct.extension):

* every point x is described by its position and the shape of the sparse cloud around it (its K
  nearest sparse points relative to x, through a small PointNet): the local evidence;
* a global vector pools the sparse cloud and the fitted rods' points;
* per fitted pipe, a masked max over its fitted points' features: the pipe's context;
* per candidate point, from [its features; its pipe's; global; how far past the fitted part it lies]:
  a logit (inside a real pipe?) and a bounded offset — zero at initialisation.

Inputs are normalised to the sparse cloud's unit cube (gprbot.infer.gprnet.normalisation). Pipes are
one-hot columns; a point whose row is all zero sees no pipe feature.
"""

from __future__ import annotations

import itertools

import torch
from torch import nn

NEIGHBOURS = 16
MAX_OFFSET = 0.05  # the largest correction, in unit-cube units (5–15 cm on the training surveys)


def _mlp(*widths: int, last_relu: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(itertools.pairwise(widths)):
        layers.append(nn.Linear(a, b))
        if last_relu or i < len(widths) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def masked_max(features: torch.Tensor, onehot: torch.Tensor) -> torch.Tensor:
    """Per column of onehot (B, N, P): the max of features (B, N, C) over its points → (B, P, C); 0 if none."""
    big = 1e4
    shifted = features.unsqueeze(2) - big * (1.0 - onehot).unsqueeze(-1)  # (B, N, P, C)
    pooled = shifted.max(dim=1).values
    return torch.where(onehot.sum(dim=1).unsqueeze(-1) > 0, pooled, torch.zeros_like(pooled))


class FitRefiner(nn.Module):
    """Acceptance logits and moved points for candidate rod points, from the sparse cloud and the fitted rods."""

    def __init__(self, local: int = 64, point: int = 128, global_dim: int = 256, hidden: int = 128) -> None:
        super().__init__()
        self.neighbour_mlp = _mlp(4, 32, local)
        self.point_mlp = _mlp(3 + local, point, point)
        self.sparse_mlp = _mlp(3, 64, point)
        self.global_mlp = _mlp(point, global_dim, global_dim)
        self.head = _mlp(2 * point + global_dim + 1, hidden, hidden)
        self.logit = nn.Linear(hidden, 1)
        self.offset = nn.Linear(hidden, 3)
        nn.init.zeros_(self.offset.weight)
        nn.init.zeros_(self.offset.bias)

    def describe(self, points: torch.Tensor, sparse: torch.Tensor) -> torch.Tensor:
        """Per-point features (B, N, point) from the position and the K nearest sparse points around it."""
        distances = torch.cdist(points, sparse)  # (B, N, S)
        index = distances.topk(NEIGHBOURS, dim=2, largest=False).indices  # (B, N, K)
        b, n, k = index.shape
        near = torch.gather(sparse, 1, index.reshape(b, n * k, 1).expand(-1, -1, 3)).reshape(b, n, k, 3)
        relative = near - points.unsqueeze(2)
        gap = relative.norm(dim=-1, keepdim=True)
        local = self.neighbour_mlp(torch.cat([relative, gap], dim=-1)).max(dim=2).values
        return self.point_mlp(torch.cat([points, local], dim=-1))  # type: ignore[no-any-return]

    def forward(
        self, sparse: torch.Tensor, fit: torch.Tensor, fit_onehot: torch.Tensor, query: torch.Tensor,
        query_onehot: torch.Tensor, beyond: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(B,S,3), (B,F,3), (B,F,P), (B,Q,3), (B,Q,P), (B,Q,1) → logits (B,Q), moved query (B,Q,3)."""
        fit_features = self.describe(fit, sparse)
        pooled = torch.cat([self.sparse_mlp(sparse), fit_features], dim=1).max(dim=1).values
        global_feature = self.global_mlp(pooled)  # (B, G)
        pipes = masked_max(fit_features, fit_onehot)  # (B, P, C)
        own_pipe = torch.bmm(query_onehot, pipes)  # (B, Q, C)
        g_query = global_feature.unsqueeze(1).expand(-1, query.shape[1], -1)
        hidden = self.head(torch.cat([self.describe(query, sparse), own_pipe, g_query, beyond], dim=-1))
        return self.logit(hidden).squeeze(-1), query + MAX_OFFSET * torch.tanh(self.offset(hidden))


def example_inputs(batch: int, fit: int = 1024, query: int = 4096, pipes: int = 12) -> tuple[torch.Tensor, ...]:
    """Inputs shaped and distributed as the runtime's (points in the unit cube, one-hot pipes), for export checks."""
    gen = torch.Generator().manual_seed(0)

    def cube(n: int) -> torch.Tensor:
        return torch.rand(batch, n, 3, generator=gen) - 0.5

    def owners(n: int) -> torch.Tensor:
        return nn.functional.one_hot(torch.randint(0, pipes, (batch, n), generator=gen), pipes).float()

    beyond = 0.1 * torch.rand(batch, query, 1, generator=gen)
    return cube(1500), cube(fit), owners(fit), cube(query), owners(query), beyond


def build_fit_refiner(**cfg: object) -> FitRefiner:
    """The exporter's builder (tools/export_onnx.py)."""
    return FitRefiner(**cfg)  # type: ignore[arg-type]
