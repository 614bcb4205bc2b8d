"""MS-SSIM (the study's variant): ``alpha·(1 - MS-SSIM)/2 + (1 - alpha)·L1`` per scale.

Box windows of ``kernel_size`` at ``levels`` levels, "same" padding, Wang's (or equal, or
learned) level weights; all scales of the pyramid through the kernels together.
"""

from __future__ import annotations

from typing import Sequence

from torch import Tensor

from msdepth.config.params import LossConfig
from msdepth.config.variants.msssim import MSSSIMConfig
from msdepth.losses.appearance import term
from msdepth.losses.monodepth import AppearanceTerm, similarity_appearance_loss
from msdepth.losses.ssim import LearnedLevelWeights, PyramidSimilarity, ms_ssim_pyramid


def _msssim_similarity(
    cfg: MSSSIMConfig, learned_weights: LearnedLevelWeights | None = None, implementation: str = "fast"
) -> PyramidSimilarity:
    """``(xs, ys) -> [MS-SSIM(xs[i], ys[i]) per image]`` of a scale pyramid, all scales together.

    With ``cfg.weights == "learned"``, ``learned_weights`` must be given; it is called on every use,
    so the current parameter values (and their gradient) are used.
    """
    if cfg.weights == "learned" and learned_weights is None:
        raise ValueError("msssim weights 'learned' need a LearnedLevelWeights module")

    def similarity(xs: Sequence[Tensor], ys: Sequence[Tensor]) -> list[Tensor]:
        weights = cfg.weights if learned_weights is None else learned_weights()
        values = ms_ssim_pyramid(
            xs,
            ys,
            cfg.kernel_size,
            cfg.levels,
            weights=weights,
            implementation=implementation,  # type: ignore[arg-type]
        )
        return list(values)

    return similarity


@term("msssim")
class MSSSIMAppearance(AppearanceTerm):
    """Per scale, ``alpha·mean(clip((1 - MS-SSIM)/2)) + (1 - alpha)·mean|x - y|``; holds
    :class:`LearnedLevelWeights` as ``level_weights`` when ``cfg.weights == "learned"``."""

    def __init__(self, cfg: MSSSIMConfig, loss_cfg: LossConfig) -> None:
        super().__init__()
        self.cfg, self.alpha, self.implementation = cfg, loss_cfg.alpha, loss_cfg.kernels
        if cfg.weights == "learned":
            self.level_weights = LearnedLevelWeights(cfg.levels)

    def forward(self, estimates: Sequence[Tensor], targets: Sequence[Tensor]) -> list[Tensor]:
        """Per scale, the appearance loss of ``estimates[s]`` against ``targets[s]``."""
        # Built per call (cheap) rather than stored, so copies of this module never keep a
        # closure over another copy's level weights.
        similarity = _msssim_similarity(self.cfg, getattr(self, "level_weights", None), self.implementation)
        return [
            similarity_appearance_loss(sim, x, y, self.alpha)
            for sim, x, y in zip(similarity(estimates, targets), estimates, targets, strict=True)
        ]
