"""MigrationNet: a B-scan tile (in depth) → the probability that each pixel lies inside a pipe.

After the paper's architecture: a multi-resolution encoder of three branches that reach 1/16 of the
input by max-pooling 8 (then 2), 4-2-2 and 2-2-2, concatenated; five up-sampling groups with skip
connections (from the 2-2-2 branch at 1/2, 1/4, 1/8, from the concatenation at 1/16 and from a
full-resolution stem) back to the input grid; a sigmoid mask. Widths are narrow (`width`) so that it
trains on one CPU thread in half an hour and runs in tens of milliseconds in onnxruntime.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn


def _block(c_in: int, c_out: int) -> nn.Sequential:
    """Two 3×3 convolutions with batch norm and ReLU."""
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, padding=1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True),
    )


class _Up(nn.Module):
    """Up-sample ×2 (bilinear), concatenate the skip, convolve."""

    def __init__(self, c_in: int, c_skip: int, c_out: int) -> None:
        super().__init__()
        self.up = nn.Upsample(scale_factor=2, mode="bilinear", align_corners=False)
        self.conv = _block(c_in + c_skip, c_out)

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        return self.conv(torch.cat([self.up(x), skip], dim=1))


class MigrationNet(nn.Module):
    """Multi-resolution encoder (3 branches), 5 up-sampling groups with skips, one-channel logits out.

    Input (B, 1, H, W) with H and W multiples of 32; output logits (B, 1, H, W). `probabilities`
    applies the sigmoid (the exported graph ends with it).
    """

    def __init__(self, width: int = 8, in_channels: int = 1) -> None:
        super().__init__()
        w = width
        self.stem = _block(in_channels, w)  # full resolution, skip for the last group
        # branch "coarse": max-pool 8, conv, max-pool 2 → 1/16
        self.coarse = nn.Sequential(nn.MaxPool2d(8), _block(w, 2 * w), nn.MaxPool2d(2))
        # branch "middle": max-pool 4-2-2 → 1/16
        self.middle = nn.Sequential(
            nn.MaxPool2d(4), _block(w, 2 * w), nn.MaxPool2d(2), _block(2 * w, 2 * w), nn.MaxPool2d(2)
        )
        # branch "fine": max-pool 2-2-2 with skips at 1/2, 1/4, 1/8, then 2 more → 1/16
        self.fine1 = nn.Sequential(nn.MaxPool2d(2), _block(w, 2 * w))
        self.fine2 = nn.Sequential(nn.MaxPool2d(2), _block(2 * w, 3 * w))
        self.fine3 = nn.Sequential(nn.MaxPool2d(2), _block(3 * w, 4 * w))
        self.fine_out = nn.MaxPool2d(2)
        merged = 2 * w + 2 * w + 4 * w
        self.merge = _block(merged, 6 * w)  # 1/16
        self.bottom = nn.Sequential(nn.MaxPool2d(2), _block(6 * w, 8 * w))  # 1/32
        self.up1 = _Up(8 * w, 6 * w, 6 * w)  # → 1/16
        self.up2 = _Up(6 * w, 4 * w, 4 * w)  # → 1/8
        self.up3 = _Up(4 * w, 3 * w, 3 * w)  # → 1/4
        self.up4 = _Up(3 * w, 2 * w, 2 * w)  # → 1/2
        self.up5 = _Up(2 * w, w, w)  # → 1
        self.head = nn.Conv2d(w, 1, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits (B, 1, H, W)."""
        s0 = self.stem(x)
        f1 = self.fine1(s0)
        f2 = self.fine2(f1)
        f3 = self.fine3(f2)
        merged = self.merge(torch.cat([self.coarse(s0), self.middle(s0), self.fine_out(f3)], dim=1))
        y = self.bottom(merged)
        y = self.up1(y, merged)
        y = self.up2(y, f3)
        y = self.up3(y, f2)
        y = self.up4(y, f1)
        y = self.up5(y, s0)
        logits: torch.Tensor = self.head(y)
        return logits


class MigrationNetProbabilities(nn.Module):
    """The exported graph: MigrationNet followed by the sigmoid."""

    def __init__(self, net: MigrationNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.net(x))


def build_migrationnet(**cfg: Any) -> nn.Module:
    """The export registry's builder: MigrationNet(**cfg) wrapped to output probabilities."""
    return MigrationNetProbabilities(MigrationNet(**cfg))


def bce_dice_loss(logits: torch.Tensor, target: torch.Tensor, smooth: float = 1.0) -> torch.Tensor:
    """Binary cross-entropy plus soft Dice loss (Dice over each image, averaged over the batch)."""
    bce = nn.functional.binary_cross_entropy_with_logits(logits, target)
    p = torch.sigmoid(logits).flatten(1)
    t = target.flatten(1)
    dice = (2.0 * (p * t).sum(1) + smooth) / (p.sum(1) + t.sum(1) + smooth)
    return bce + (1.0 - dice).mean()
