"""Monodepth's VGG encoder-decoder (Godard et al. 2017; dissertation Figure 2.2).

From the left image it predicts left and right disparities, as a fraction of the image
width, at 4 scales (1/1, 1/2, 1/4, 1/8). ``width_multiplier`` scales every channel count,
so 1.0 is the paper's model (~31 M parameters) and 0.25 runs on a laptop CPU.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from msdepth.networks.common import MAX_DISPARITY, scaled_channels

# (kernel, channels) of the encoder blocks conv1..conv7; each block is a stride-2 conv
# followed by a stride-1 conv ("convNb"), as in the dissertation's table.
ENCODER = ((7, 32), (5, 64), (3, 128), (3, 256), (3, 512), (3, 512), (3, 512))
# Output channels of upconv7..upconv1 (the iconv after each has the same width).
DECODER = (512, 512, 256, 128, 64, 32, 16)

Norm = Literal["none", "group"]
NORMS = ("none", "group")
Heads = Literal["independent", "residual"]
HEADS = ("independent", "residual")


def _group_count(channels: int) -> int:
    """GroupNorm groups for a layer: about 4 channels per group, at most 32 (Wu & He 2018's
    default), and a divisor of ``channels``."""
    return math.gcd(channels, min(32, max(1, channels // 4)))


def _conv(in_ch: int, out_ch: int, kernel: int, stride: int = 1, norm: Norm = "none") -> nn.Sequential:
    # Zero padding of (k-1)//2 then a conv, ELU, as in Monodepth's `conv`; with norm="group" a
    # GroupNorm between them (per image, so batch size and data parallelism do not change it).
    pad = (kernel - 1) // 2
    if norm == "none":
        return nn.Sequential(nn.Conv2d(in_ch, out_ch, kernel, stride, pad), nn.ELU(inplace=True))
    return nn.Sequential(
        nn.Conv2d(in_ch, out_ch, kernel, stride, pad, bias=False),
        nn.GroupNorm(_group_count(out_ch), out_ch),
        nn.ELU(inplace=True),
    )


class MonodepthVGG(nn.Module):
    """The VGG depth network; ``forward`` returns 4 disparity maps, finest first.

    Each map has 2 channels (0 = left disparity, 1 = right disparity) in fractions of the
    width at that scale. Any input size works (upsampling follows the skip's size); sizes
    divisible by 8 make the 4 outputs exact halvings.

    ``norm="none"`` and ``heads="independent"`` are the dissertation's network. ``norm="group"``
    puts a GroupNorm after every convolution but the disparity heads. ``heads="residual"`` makes
    each finer head predict a correction to the coarser scale's disparity (added in logit space
    to its bilinear upsampling), coarse to fine: the finest map starts from what the coarse
    scales learned instead of from its own initial value.
    """

    def __init__(
        self,
        width_multiplier: float = 1.0,
        init_disparity: float | None = None,
        norm: Norm = "none",
        heads: Heads = "independent",
    ) -> None:
        super().__init__()
        if norm not in NORMS:
            raise ValueError(f"MonodepthVGG: norm must be one of {NORMS}, got {norm!r}")
        if heads not in HEADS:
            raise ValueError(f"MonodepthVGG: heads must be one of {HEADS}, got {heads!r}")
        self.norm, self.residual = norm, heads == "residual"
        enc = [(k, scaled_channels(c, width_multiplier)) for k, c in ENCODER]
        dec = [scaled_channels(c, width_multiplier) for c in DECODER]
        self.encoder = nn.ModuleList()
        in_ch = 3
        for kernel, ch in enc:
            self.encoder.append(
                nn.Sequential(_conv(in_ch, ch, kernel, 2, norm), _conv(ch, ch, kernel, 1, norm))
            )
            in_ch = ch
        skips = [ch for _, ch in enc[:-1]][::-1]  # conv6b .. conv1b
        self.upconvs = nn.ModuleList()
        self.iconvs = nn.ModuleList()
        self.heads = nn.ModuleList()
        for i, ch in enumerate(dec):
            self.upconvs.append(_conv(in_ch, ch, 3, 1, norm))
            skip = skips[i] if i < len(skips) else 0
            # The three finest iconvs also take the upsampled coarser disparity ("+disp*").
            extra = 2 if i >= 4 else 0
            self.iconvs.append(_conv(ch + skip + extra, ch, 3, 1, norm))
            if i >= 3:  # iconv4 .. iconv1 feed disp4 .. disp1
                self.heads.append(nn.Conv2d(ch, 2, 3, 1, 1))
            in_ch = ch
        if init_disparity is not None:
            self.init_heads(init_disparity)

    def init_heads(self, disparity: float) -> None:
        """Start every head near ``disparity`` (fraction of width) with small weights.

        A network that starts at 0.15 (sigmoid(0)) of the width predicts ~30 px at 192 px
        and can stall in the smoothness minimum; starting near typical disparities lets
        small, short runs learn (see docs/design.md).
        """
        bias = math.log(disparity / (MAX_DISPARITY - disparity))  # logit(disparity / 0.3)
        for i, head in enumerate(self.heads):
            nn.init.normal_(head.weight, std=1e-3)
            # Residual heads: only the coarsest (the first) sets the level, the others add to it.
            nn.init.constant_(head.bias, 0.0 if self.residual and i > 0 else bias)

    def forward(self, image: Tensor) -> list[Tensor]:
        feats = []
        x = image
        for block in self.encoder:
            x = block(x)
            feats.append(x)
        skips = feats[:-1][::-1]  # conv6b .. conv1b
        disps: list[Tensor] = []
        logits: Tensor | None = None
        for i, (up, iconv) in enumerate(zip(self.upconvs, self.iconvs, strict=True)):
            size = skips[i].shape[-2:] if i < len(skips) else image.shape[-2:]
            x = up(F.interpolate(x, size=size, mode="nearest"))
            parts = [x]
            if i < len(skips):
                parts.append(skips[i])
            if i >= 4:
                parts.append(F.interpolate(disps[-1], size=size, mode="nearest"))
            x = iconv(torch.cat(parts, dim=1))
            if i >= 3:
                head = self.heads[i - 3](x)
                if self.residual and logits is not None:
                    head = head + F.interpolate(logits, size=size, mode="bilinear", align_corners=False)
                logits = head
                disps.append(MAX_DISPARITY * torch.sigmoid(head))
        return disps[::-1]
