"""The ``mix`` section: Zhao et al.'s MS-SSIM + Gaussian-weighted L1 term
(:mod:`msdepth.losses.appearance.mix`,
whose docstring explains the defaults)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, ClassVar, Literal

from msdepth.config.checks import MAX_KERNEL_SIZE, MAX_SSIM_LEVELS, Range, check, check_levels_fit
from msdepth.config.variants import register

if TYPE_CHECKING:
    from msdepth.config.params import Params


MAX_SIGMA = 64.0  # px, the Gaussian window's sigma (0.5 by default)


@register("mix")
@dataclass(frozen=True)
class MixConfig:
    # No per-pixel form of its term (msdepth.optimum.cost_volume): optimum.start: cost cannot match on it.
    per_pixel_cost: ClassVar[bool] = False
    alpha: Annotated[float, Range(0, 1)] = 0.84  # Zhao et al.'s weight of the MS-SSIM term
    # 5 in Zhao et al.; needs an input whose coarsest training scale has 16 px
    levels: Annotated[int, Range(1, MAX_SSIM_LEVELS)] = 4
    # px, the Gaussian window of every level (level i: sigma·2^i px of the image)
    sigma: Annotated[float, Range(0, MAX_SIGMA, low_open=True)] = 0.5
    kernel_size: Annotated[int, Range(1, MAX_KERNEL_SIZE)] = 5  # taps of that window (±4σ at 0.5 px)
    weights: Literal["ones", "wang", "equal"] = "ones"  # ones: Zhao et al.'s exponents of 1

    @property
    def l1_sigma(self) -> float:
        """σ of the L1 weighting: the coarsest level's Gaussian, in px of the compared image."""
        return self.sigma * 2 ** (self.levels - 1)

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section; a ConfigError names the key."""
        k, d = self.kernel_size, params.data
        check(0 <= self.alpha <= 1, f"{key}.alpha", f"must be in [0, 1], got {self.alpha}")
        check(self.sigma > 0, f"{key}.sigma", f"must be > 0, got {self.sigma}")
        check(k >= 1 and k % 2 == 1, f"{key}.kernel_size", f"must be a positive odd integer, got {k}")
        check(k <= min(d.height, d.width), f"{key}.kernel_size", "must not exceed the input image")
        check_levels_fit(key, self.levels, d.height, d.width)
