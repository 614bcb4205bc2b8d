"""The ``msssim`` section: the study's MS-SSIM term (:mod:`msdepth.losses.appearance.msssim`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, ClassVar, Literal

from msdepth.config.checks import MAX_KERNEL_SIZE, MAX_SSIM_LEVELS, Range, check, check_levels_fit
from msdepth.config.variants import register

if TYPE_CHECKING:
    from msdepth.config.params import Params


@register("msssim")
@dataclass(frozen=True)
class MSSSIMConfig:
    # A per-pixel form of its term exists (msdepth.optimum.cost_volume): optimum.start: cost can match on it.
    per_pixel_cost: ClassVar[bool] = True
    kernel_size: Annotated[int, Range(1, MAX_KERNEL_SIZE)] = 3
    levels: Annotated[int, Range(1, MAX_SSIM_LEVELS)] = 4
    weights: Literal["wang", "equal", "learned"] = "wang"

    def validate(self, key: str, params: Params) -> None:
        """Range checks of the ``key`` section; a ConfigError names the key."""
        k, d = self.kernel_size, params.data
        check(k >= 1 and k % 2 == 1, f"{key}.kernel_size", f"must be a positive odd integer, got {k}")
        check(k <= min(d.height, d.width), f"{key}.kernel_size", "must not exceed the input image")
        check_levels_fit(key, self.levels, d.height, d.width)
