"""SSIM (Monodepth): ``alpha·(1 - SSIM)/2 + (1 - alpha)·L1`` per scale, 3x3 box windows by default."""

from __future__ import annotations

from typing import Sequence

from torch import Tensor

from msdepth.config.params import LossConfig
from msdepth.config.variants.ssim import SSIMConfig
from msdepth.losses.appearance import term
from msdepth.losses.monodepth import AppearanceTerm, similarity_appearance_loss
from msdepth.losses.ssim import ssim


@term("ssim")
class SSIMAppearance(AppearanceTerm):
    """Per scale, Monodepth's ``alpha·mean(clip((1 - SSIM)/2)) + (1 - alpha)·mean|x - y|``."""

    def __init__(self, cfg: SSIMConfig, loss_cfg: LossConfig) -> None:
        super().__init__()
        self.cfg, self.alpha, self.implementation = cfg, loss_cfg.alpha, loss_cfg.kernels

    def forward(self, estimates: Sequence[Tensor], targets: Sequence[Tensor]) -> list[Tensor]:
        """Per scale, the appearance loss of ``estimates[s]`` against ``targets[s]``."""
        k, padding = self.cfg.kernel_size, self.cfg.padding
        similarities = [
            ssim(x, y, kernel_size=k, padding=padding, implementation=self.implementation)
            for x, y in zip(estimates, targets, strict=True)
        ]
        return [
            similarity_appearance_loss(sim, x, y, self.alpha)
            for sim, x, y in zip(similarities, estimates, targets, strict=True)
        ]
