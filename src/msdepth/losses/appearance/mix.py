"""Zhao, Gallo, Frosio & Kautz (2017), "Loss Functions for Image Restoration with Neural Networks":
``alpha·(1 - MS-SSIM) + (1 - alpha)·mean(G_σ ⊛ |x - y|)`` per scale, their alpha = 0.84.

Their MS-SSIM uses Gaussian windows of σ_G^i = 0.5, 1, 2, 4, 8 px at full resolution; ours halves
the images between levels (Wang et al.), so one window of ``sigma`` = 0.5 px at every level is
``sigma·2^i`` px of the compared image at level i: the same σ_G^i. The L1 map is weighted by the
Gaussian of the coarsest level, ``sigma·2^(levels-1)`` px (their σ_G^M = 8 for 5 levels), with
"same" padding that divides by the window's mass inside the image (so a constant |x - y| = c
gives c). Their level exponents are all 1 (``weights: ones``: the product of the levels' values).
Defaults: 4 levels, since the 64 x 192 input's coarsest training scale (8 x 24 px) has no fifth.
"""

from __future__ import annotations

import math
from typing import Sequence

from torch import Tensor

from msdepth.config.params import LossConfig
from msdepth.config.variants.mix import MixConfig
from msdepth.losses.appearance import term
from msdepth.losses.monodepth import AppearanceTerm
from msdepth.losses.ssim import ms_ssim_pyramid, window_mean


def _gaussian_l1(x: Tensor, y: Tensor, sigma: float) -> Tensor:
    """``mean(G_σ ⊛ |x - y|)``: every pixel's L1 error averaged over its Gaussian neighbourhood
    (±3σ window, "same" padding divided by the in-image mass)."""
    kernel_size = 2 * math.ceil(3 * sigma) + 1
    return window_mean((x - y).abs(), kernel_size, "gaussian", sigma, "same").mean()


@term("mix")
class MixAppearance(AppearanceTerm):
    """Per scale, Zhao et al.'s ``alpha·mean(1 - MS-SSIM) + (1 - alpha)·mean(G_σ ⊛ |x - y|)``."""

    def __init__(self, cfg: MixConfig, loss_cfg: LossConfig) -> None:
        super().__init__()
        self.cfg, self.implementation = cfg, loss_cfg.kernels

    def forward(self, estimates: Sequence[Tensor], targets: Sequence[Tensor]) -> list[Tensor]:
        """Per scale, the mix of ``estimates[s]`` against ``targets[s]``."""
        cfg = self.cfg
        weights = [1.0] * cfg.levels if cfg.weights == "ones" else cfg.weights
        msssim = ms_ssim_pyramid(
            estimates,
            targets,
            cfg.kernel_size,
            cfg.levels,
            weights,
            "gaussian",
            cfg.sigma,
            "same",
            self.implementation,  # type: ignore[arg-type]
        )
        return [
            cfg.alpha * (1 - value).mean() + (1 - cfg.alpha) * _gaussian_l1(x, y, cfg.l1_sigma)
            for value, x, y in zip(msssim, estimates, targets, strict=True)
        ]
