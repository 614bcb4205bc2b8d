"""SSIM (Monodepth): ``alpha·(1 - SSIM)/2 + (1 - alpha)·L1`` per scale, 3x3 box windows by default."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, Sequence

from torch import Tensor

from ..config import LossConfig, check
from ..losses import AppearanceTerm, similarity_appearance_loss, ssim
from . import register

if TYPE_CHECKING:
    from ..config import Params


@dataclass(frozen=True)
class SSIMConfig:
    kernel_size: int = 3
    padding: Literal["valid", "reflect"] = "valid"

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section; a ConfigError names the key."""
        k, d = self.kernel_size, params.data
        check(k >= 1 and k % 2 == 1, f"{key}.kernel_size", f"must be a positive odd integer, got {k}")
        if self.padding == "valid":  # SSIM's valid windows must fit the coarsest scale (input / 8)
            smallest = min(d.height, d.width) // 8
            check(
                k <= smallest,
                f"{key}.kernel_size",
                f"{k} px windows do not fit the coarsest training scale "
                f"({d.height // 8}x{d.width // 8} px) with valid padding",
            )


@register("ssim", SSIMConfig)
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
            for x, y in zip(estimates, targets)
        ]
        return [
            similarity_appearance_loss(sim, x, y, self.alpha)
            for sim, x, y in zip(similarities, estimates, targets)
        ]
