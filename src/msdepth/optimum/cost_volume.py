"""A plane-sweep cost volume of a loss variant's own appearance term: per left pixel and integer
disparity ``d = 0 … D``, the per-pixel cost of reconstructing the left view from the right one
shifted by ``d``, ``α·clip((1 − S)/2, 0, 1) + (1 − α)·|Î − I|`` averaged over the colour channels
(``α`` = ``loss.alpha``), which is what training averages over the image.

The shift is training's reconstruction: left pixel x takes right pixel ``x − d``, and a column
left of the right image reads its edge column (``warp(right, -d/W)`` with ``loss.padding_mode``
``border``, the default, exact at an integer ``d``; ``zeros`` mode's one-pixel fade is not
reproduced). ``D`` defaults to the network heads' range, ``0.3·W``
(:data:`msdepth.networks.common.MAX_DISPARITY`), the range the optimum searches.

``ssim``: ``S`` is the variant's SSIM map (box window of ``ssim.kernel_size``, the loss's own
:func:`msdepth.losses.ssim.ssim`), reflect-padded so that it is full size. Training with
``ssim.padding: valid`` averages the map's interior, where the two are equal, so
``α·mean_interior(SSIM part) + (1 − α)·mean(L1 part)`` of the volume's slice ``d`` is training's term
of that reconstruction; with ``padding: reflect`` the slice's plain mean is.

``msssim`` (the per-pixel form). Training computes, per image and channel c,
``MS_c = Π_l max(ε, mean_p m_l(p))^{w_l}``, with ``m_l`` the contrast-structure map ``cs_l`` of
level l < L − 1 and the full SSIM map (luminance · cs) of the coarsest level L − 1, box windows of
``msssim.kernel_size`` with "same" padding, levels halved by pytorch-msssim's 2×2 pooling, ``w_l``
the level weights (Wang's or equal; ``learned`` ones at their initial value, equal) and ``ε`` the
floor training puts under each level's value (:data:`MS_SSIM_FLOOR`); then ``S = mean_c MS_c``.
The per-pixel form replaces each level's mean by that level's map around the pixel, collapsed
coarse to fine like a Laplacian pyramid:

    P_{L-1} = max(ε, m_{L-1})^{w_{L-1}},   P_l = max(ε, m_l)^{w_l} · U(P_{l+1}),   M_c = P_0,

where U resamples a level to the next finer one bilinearly at the true centres of its 2×2 cells
(:func:`_upsample`). The cost is ``mean_c[α·clip((1 − M_c(p))/2, 0, 1) + (1 − α)·|Î_c(p) − I_c(p)|]``.
Where every level's map is constant, ``M_c(p) = MS_c`` and the slice's mean is training's term
exactly (U keeps a constant); elsewhere a pixel weighs the structure around it at each level's
scale, where training's one number weighs the whole image's means (a product of means, not a
mean of products). The maps are training's own (:func:`msdepth.losses.ssim_kernels.ssim_terms`
and ``downsample``, the kernels :func:`msdepth.losses.ssim.ms_ssim` runs on).

Both volumes are the finest of training's 4 scales; its scales 1–3 (the same term on the
area-halved pair) are left out. A volume is built in blocks of disparities (and, for SSIM, rows)
of about :data:`BLOCK_ELEMENTS`, so that beside the ``(H, W, D + 1)`` float32 volume a build holds
a bounded working set (tens of MB) that stays in cache.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from msdepth.config.params import Params
from msdepth.config.variants.msssim import MSSSIMConfig
from msdepth.config.variants.ssim import SSIMConfig
from msdepth.errors import ConfigError, DataError
from msdepth.losses import ssim_kernels
from msdepth.losses.ssim import level_weights, ssim
from msdepth.networks.common import MAX_DISPARITY

# Elements of one block of a sweep's inputs (disparities x channels x rows x columns): about
# 4 MB, so that the maps the SSIM kernels and the cost derive from it stay in the CPU's caches
# (SSIM on whole-image planes measured ~1.6x slower per disparity: memory-bound passes).
BLOCK_ELEMENTS = 1 << 20
DISPARITIES_PER_BLOCK = 8  # the SSIM sweep's; its rows per block follow from BLOCK_ELEMENTS
# Training's floor of a level's MS-SSIM value before the power (msdepth.losses.ssim keeps it
# private, and a change there would stale every stage that depends on the loss's code);
# tests/test_matcher.py checks that anticorrelated images meet the same floor as ms_ssim.
MS_SSIM_FLOOR = 1e-6


@dataclass(frozen=True)
class MatchingCost:
    """A variant's appearance term as a per-pixel matching cost.

    ``weights``: the MS-SSIM level weights (fine -> coarse), training's float32 values; empty for
    single-scale SSIM.
    """

    alpha: float
    kernel_size: int
    weights: tuple[float, ...] = ()

    @property
    def levels(self) -> int:
        """MS-SSIM levels (1: SSIM)."""
        return max(1, len(self.weights))


def matching_cost(params: Params, variant: str) -> MatchingCost:
    """The per-pixel cost of a registered ``ssim``- or ``msssim``-type variant's section (any name
    in ``params.appearance``, configured or not, as the optimum's); ``α`` from ``params.loss``."""
    if variant not in params.appearance:
        raise ConfigError(
            f"cost volume: unknown variant {variant!r}; registered: {sorted(params.appearance)}"
        )
    section = params.appearance[variant]
    if isinstance(section, SSIMConfig):
        return MatchingCost(params.loss.alpha, section.kernel_size)
    if isinstance(section, MSSSIMConfig):
        spec = "equal" if section.weights == "learned" else section.weights  # learned: their start
        weights = level_weights(spec, section.levels, torch.zeros((), dtype=torch.float32))
        return MatchingCost(params.loss.alpha, section.kernel_size, tuple(weights.tolist()))
    raise ConfigError(
        f"cost volume: variant {variant!r} ({type(section).__name__}) has no per-pixel form: "
        "set optimum.start to sgbm or constant"
    )


def default_max_disparity(width: int) -> int:
    """``D``: the network heads' largest disparity, ``0.3·W`` px, rounded down."""
    return int(math.floor(MAX_DISPARITY * width))


def _upsample(image: Tensor, size: tuple[int, int]) -> Tensor:
    """A map of MS-SSIM level l + 1 resampled to level l's ``size``: bilinear ×2 at the true centres
    of the 2×2 cells (pytorch-msssim pads ``n % 2`` px on both sides before pooling, so cell i covers
    level-l pixels ``2i - p`` and ``2i + 1 - p``: the ×2 grid, cropped by ``p``)."""
    height, width = size
    up = F.interpolate(image, scale_factor=2.0, mode="bilinear", align_corners=False)
    return up[..., height % 2 : height % 2 + height, width % 2 : width % 2 + width]


def pyramid(image: Tensor, levels: int) -> list[Tensor]:
    """``image`` at each MS-SSIM level (fine -> coarse), halved by training's 2×2 pooling."""
    out = [image]
    for _ in range(1, levels):
        out.append(ssim_kernels.downsample(out[-1]))
    return out


def _level_maps(
    x: Tensor, y: Tensor, kernel_size: int, levels: int, y_levels: Sequence[Tensor] = ()
) -> list[Tensor]:
    """Training's MS-SSIM maps of (B, C, H, W) images, each at its level's size (fine -> coarse): the
    contrast-structure map of every level but the last, the SSIM map of the last; training averages
    each over its level (:func:`msdepth.losses.ssim_kernels.ms_ssim_levels`).

    ``y_levels``: ``y``'s :func:`pyramid`, if already at hand (a sweep's target, the same for every
    disparity), with a batch of 1 or of ``x``'s.
    """
    ys = list(y_levels) or pyramid(y, levels)
    maps = []
    for level in range(levels):
        last = level == levels - 1
        value = ssim_kernels.ssim_terms(x, ys[level].expand_as(x), kernel_size, "box", 1.5, "same", last)
        maps.append(value[1] if last else value)
        if not last:
            x = ssim_kernels.downsample(x)
    return maps


def _collapse(maps: Sequence[Tensor], weights: Sequence[float]) -> Tensor:
    """The per-pixel product of the module docstring, at the finest map's size: each level's map
    floored and raised to its weight, multiplied coarse to fine, each product resampled to the
    next finer level (:func:`_upsample`). Changes ``maps`` in place."""
    terms = [m.clamp_(min=MS_SSIM_FLOOR).pow_(w) for m, w in zip(maps, weights, strict=True)]
    out = terms.pop()
    while terms:
        finer = terms.pop()
        out = finer.mul_(_upsample(out, finer.shape[-2:]))
    return out


def _ms_ssim_map(
    x: Tensor, y: Tensor, kernel_size: int, weights: Sequence[float], y_levels: Sequence[Tensor] = ()
) -> Tensor:
    """The per-pixel MS-SSIM of the module docstring, (B, C, H, W): :func:`_collapse` of
    :func:`_level_maps`."""
    return _collapse(_level_maps(x, y, kernel_size, len(weights), y_levels), weights)


def _similarity_map(cost: MatchingCost, x: Tensor, y: Tensor) -> Tensor:
    """The variant's per-pixel similarity ``S`` of (B, C, H, W) images, (B, C, H, W)."""
    if not cost.weights:
        return ssim(x, y, kernel_size=cost.kernel_size, padding="reflect")
    return _ms_ssim_map(x, y, cost.kernel_size, cost.weights)


def _appearance_map(cost: MatchingCost, estimate: Tensor, target: Tensor) -> Tensor:
    """The per-pixel appearance cost (B, H, W): ``mean_c[α·clip((1 - S)/2, 0, 1) + (1 - α)·|Î - I|]``."""
    return combined(cost, _similarity_map(cost, estimate, target), estimate, target)


def combined(cost: MatchingCost, similarity: Tensor, estimate: Tensor, target: Tensor) -> Tensor:
    """:func:`_appearance_map` given the similarity map ``S`` (consumed: changed in place)."""
    dissimilarity = similarity.neg_().add_(1).mul_(0.5).clamp_(0, 1).mul_(cost.alpha)
    return dissimilarity.add_((estimate - target).abs_().mul_(1 - cost.alpha)).mean(1)


def _shift_index(width: int, disparities: Sequence[int], pad: int = 0) -> Tensor:
    """(n, width + 2·pad) column indices into the right image of its shift by each disparity,
    reflect-padded by ``pad``: padded column j reads ``max(reflect(j - pad) - d, 0)``."""
    columns = torch.arange(-pad, width + pad)
    columns = columns.abs()
    columns = torch.where(columns > width - 1, 2 * (width - 1) - columns, columns)
    return torch.stack([(columns - d).clamp_(min=0) for d in disparities])


def shifted(right: Tensor, disparities: Sequence[int]) -> Tensor:
    """(n, C, H, W): ``right`` (C, H, W) shifted right by each disparity, ``out[d][..., x] =
    right[..., max(x - d, 0)]`` (training's border reconstruction of the left view)."""
    return right[..., _shift_index(right.shape[-1], disparities).to(right.device)].permute(2, 0, 1, 3)


# Peak bytes per cell of an (H, W, D + 1) volume on the cost start's path: the float32 volume, SGM's
# int16 steps, path costs and sums. Measured: 726 MiB above the constant start's peak at 1024 x 512
# px, D = 307 (4.7 B a cell); 8 leaves room. The volume grows with H·W², so without a bound the
# optimum CLI's own-size limit (4096 x 4096 px) would ask for about 150 GiB.
VOLUME_BYTES_PER_CELL = 8
MAX_VOLUME_BYTES = 8 << 30  # KITTI's 375 x 1242 px at D = 372: 1.3 GiB


def _volume_bytes(height: int, width: int, max_disparity: int | None = None) -> int:
    """The cost start's estimated peak bytes for an ``height`` x ``width`` pair (D as in
    :func:`cost_volume`): (H·W·(D + 1)) cells of :data:`VOLUME_BYTES_PER_CELL`."""
    top = default_max_disparity(width) if max_disparity is None else int(max_disparity)
    return height * width * (top + 1) * VOLUME_BYTES_PER_CELL


def check_volume_size(height: int, width: int, max_disparity: int | None = None) -> None:
    """A DataError, before any allocation, when the cost volume of an ``height`` x ``width`` pair
    would take more than :data:`MAX_VOLUME_BYTES` (:func:`_volume_bytes`)."""
    need = _volume_bytes(height, width, max_disparity)
    if need > MAX_VOLUME_BYTES:
        top = default_max_disparity(width) if max_disparity is None else int(max_disparity)
        raise DataError(
            f"the cost volume of a {width} x {height} px pair at {top + 1} disparities would take about "
            f"{need / 2**30:.1f} GiB, over the cost start's {MAX_VOLUME_BYTES / 2**30:g} GiB (it runs at the "
            "pair's own size, halved within optimum.max_width): lower optimum.max_width, choose "
            "optimum.start sgbm or constant, or give the pair smaller"
        )


def cost_volume(left: Tensor, right: Tensor, cost: MatchingCost, max_disparity: int | None = None) -> Tensor:
    """The (H, W, D + 1) float32 cost of every left pixel at disparities 0 … D (D: ``max_disparity``,
    default :func:`default_max_disparity`), for a (C, H, W) pair in [0, 1]. Layout: disparity last,
    as :mod:`msdepth.optimum.sgm` reads it."""
    if left.dim() != 3 or left.shape != right.shape:
        shapes = f"{tuple(left.shape)} and {tuple(right.shape)}"
        raise ValueError(f"cost volume: expected two (C, H, W) images of one size, got {shapes}")
    _, height, width = left.shape
    top = default_max_disparity(width) if max_disparity is None else int(max_disparity)
    if not 0 <= top < width:
        raise ValueError(f"cost volume: max disparity {top} outside [0, {width - 1}]")
    if min(height, width) <= cost.kernel_size // 2:
        raise ValueError(
            f"cost volume: a {height}x{width} image is too small for a {cost.kernel_size} px window"
        )
    check_volume_size(height, width, top)
    volume = left.new_empty(height, width, top + 1)
    with torch.no_grad():
        if cost.weights:
            _ms_ssim_sweep(left, right, cost, volume)
        else:
            _ssim_sweep(left, right, cost, volume)
    return volume


def _ssim_sweep(left: Tensor, right: Tensor, cost: MatchingCost, volume: Tensor) -> None:
    """Fill ``volume`` by blocks of disparities x rows: the reflect-padded pair's valid SSIM on a
    block (with its ``k // 2`` px halo) is the full map's, so the blocks stay in cache."""
    channels, height, width = left.shape
    pad = cost.kernel_size // 2
    left_p = F.pad(left, (pad, pad, pad, pad), mode="reflect") if pad else left
    right_p = F.pad(right, (0, 0, pad, pad), mode="reflect") if pad else right
    count = volume.shape[-1]
    chunk = min(count, DISPARITIES_PER_BLOCK)
    rows = max(1, BLOCK_ELEMENTS // (chunk * channels * (width + 2 * pad)))
    for start in range(0, count, chunk):
        ds = range(start, min(count, start + chunk))
        index = _shift_index(width, ds, pad).to(left.device)
        for top in range(0, height, rows):
            bottom = min(height, top + rows)
            target = left_p[:, top : bottom + 2 * pad].expand(len(ds), -1, -1, -1)
            estimate = right_p[:, top : bottom + 2 * pad][..., index].permute(2, 0, 1, 3)
            similarity = ssim(estimate, target, kernel_size=cost.kernel_size, padding="valid")
            inner = (slice(None), slice(None), slice(pad, pad + bottom - top), slice(pad, pad + width))
            block = combined(cost, similarity, estimate[inner], target[inner])
            volume[top:bottom, :, start : start + len(ds)] = block.permute(1, 2, 0)


def _ms_ssim_sweep(left: Tensor, right: Tensor, cost: MatchingCost, volume: Tensor) -> None:
    """Fill ``volume`` by chunks of disparities, whole images (MS-SSIM's levels see the whole image)."""
    channels, height, width = left.shape
    count = volume.shape[-1]
    chunk = max(1, BLOCK_ELEMENTS // (channels * height * width))
    targets = pyramid(left[None], len(cost.weights))
    for start in range(0, count, chunk):
        ds = range(start, min(count, start + chunk))
        estimate = shifted(right, ds)
        target = left.expand_as(estimate)
        similarity = _ms_ssim_map(estimate, target, cost.kernel_size, cost.weights, targets)
        block = combined(cost, similarity, estimate, target)
        volume[..., start : start + len(ds)] = block.permute(1, 2, 0)


def winner_take_all(volume: Tensor) -> Tensor:
    """(H, W) float32: every pixel's lowest-cost disparity (px) of an (H, W, D + 1) volume."""
    return volume.argmin(-1).float()
