"""The ``ssim`` section: Monodepth's SSIM term (:mod:`msdepth.losses.appearance.ssim`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, ClassVar, Literal

from msdepth.config.checks import MAX_KERNEL_SIZE, Range, check
from msdepth.config.variants import register

if TYPE_CHECKING:
    from msdepth.config.params import Params


@register("ssim")
@dataclass(frozen=True)
class SSIMConfig:
    # A per-pixel form of its term exists (msdepth.optimum.cost_volume): optimum.start: cost can match on it.
    per_pixel_cost: ClassVar[bool] = True
    kernel_size: Annotated[int, Range(1, MAX_KERNEL_SIZE)] = 3
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
