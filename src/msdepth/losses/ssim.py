"""SSIM and MS-SSIM as plain functions on tensors, with the windows and level weights they use.

:func:`ssim` (a per-pixel map) and :func:`ms_ssim` (one value per image; :func:`ms_ssim_pyramid`
for every scale of a pyramid at once) run on the fast kernels of :mod:`msdepth.losses.ssim_kernels`
by default, or with ``implementation="reference"`` on the written-out autograd formula here
(:func:`_reference_ssim_terms`, :func:`window_mean`), which the fast kernels are tested against.
:func:`level_weights` resolves MS-SSIM's per-level weights; :class:`LearnedLevelWeights` holds
trainable ones. The objective that uses them is :mod:`msdepth.losses.monodepth`'s.

Images are (B, C, H, W) in [0, 1].
"""

from __future__ import annotations

from typing import Callable, Literal, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from msdepth.losses import ssim_kernels as kernels
from msdepth.losses.ssim_kernels import C1, C2, Window

__all__ = ["C1", "C2", "Window"]  # re-exported: the SSIM constants belong to the formula

Similarity = Callable[[Tensor, Tensor], Tensor]
"""``similarity(x, y)``: an SSIM map (B, C, H', W') or a per-image MS-SSIM (B,); 1 = identical."""

PyramidSimilarity = Callable[[Sequence[Tensor], Sequence[Tensor]], list[Tensor]]
"""``similarity(xs, ys)``: a :data:`Similarity` of every pair ``(xs[i], ys[i])`` of a scale pyramid."""

Implementation = Literal["fast", "reference"]
"""``fast``: :mod:`msdepth.losses.ssim_kernels`; ``reference``: autograd through the written-out formula."""

IMPLEMENTATIONS = ("fast", "reference")

# Wang, Simoncelli & Bovik (2003), 5 scales fine -> coarse.
WANG_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
# Floor for per-level MS-SSIM values before the power: d(x**w)/dx = w·x**(w-1) is unbounded as
# x -> 0+ for w < 1, so relu'd values just above 0 can overflow to inf/NaN gradients; the floor
# bounds it (about w·1e6) and makes negative contrast-structure a flat, finite region.
_MS_SSIM_EPS = 1e-6


def _check_pair(name: str, x: Tensor, y: Tensor) -> None:
    if x.dim() != 4 or x.shape != y.shape:
        raise ValueError(
            f"{name}: expected two (B, C, H, W) tensors of the same shape, "
            f"got {tuple(x.shape)} and {tuple(y.shape)}"
        )


def _check_kernel(name: str, kernel_size: int) -> None:
    if kernel_size < 1 or kernel_size % 2 != 1:
        raise ValueError(f"{name}: kernel_size must be a positive odd integer, got {kernel_size}")


def _check_implementation(name: str, implementation: str) -> None:
    if implementation not in IMPLEMENTATIONS:
        raise ValueError(f"{name}: implementation must be 'fast' or 'reference', got {implementation!r}")


# ----------------------------------------------------------------------------- reference formula


def window_mean(
    t: Tensor, kernel_size: int, window: Window, sigma: float, padding: Literal["valid", "same"]
) -> Tensor:
    """Window mean of every channel with autograd: ``avg_pool2d`` (box) or a Gaussian ``conv2d``,
    divided by the window mass inside the image (``"same"`` padding: zeros outside, not counted)."""
    pad = kernel_size // 2 if padding == "same" else 0
    if window == "box":
        return F.avg_pool2d(t, kernel_size, stride=1, padding=pad, count_include_pad=False)
    coords = torch.arange(kernel_size, dtype=torch.float64) - kernel_size // 2
    g = torch.exp(-(coords**2) / (2 * sigma**2))
    g = (g / g.sum()).to(t.dtype)
    rows = g.view(1, 1, -1, 1).expand(t.shape[1], 1, kernel_size, 1)
    cols = g.view(1, 1, 1, -1).expand(t.shape[1], 1, 1, kernel_size)

    def smooth(u: Tensor) -> Tensor:  # separable: rows, then columns
        u = F.conv2d(u, rows, padding=(pad, 0), groups=u.shape[1])
        return F.conv2d(u, cols, padding=(0, pad), groups=u.shape[1])

    return smooth(t) / smooth(torch.ones_like(t))


def _reference_ssim_terms(
    x: Tensor,
    y: Tensor,
    kernel_size: int,
    window: Window = "box",
    sigma: float = 1.5,
    padding: Literal["valid", "same"] = "valid",
) -> tuple[Tensor, Tensor]:
    """The SSIM formula written out with autograd: (contrast-structure map, SSIM map).

    The definition the fast kernels are tested against, and their fallback
    (``implementation="reference"``): simple and slow (~40 full-size temporaries per call).
    """
    mean = lambda t: window_mean(t, kernel_size, window, sigma, padding)  # noqa: E731
    mu_x, mu_y = mean(x), mean(y)
    var_x, var_y, cov = mean(x * x) - mu_x**2, mean(y * y) - mu_y**2, mean(x * y) - mu_x * mu_y
    cs = (2 * cov + C2) / (var_x + var_y + C2)
    return cs, (2 * mu_x * mu_y + C1) / (mu_x**2 + mu_y**2 + C1) * cs


def _reference_ms_ssim_levels(
    x: Tensor,
    y: Tensor,
    kernel_size: int,
    levels: int,
    window: Window,
    sigma: float,
    padding: Literal["same", "valid"],
) -> Tensor:
    """(levels, B, C): mean cs of each level but the last, mean SSIM of the last; one level at a
    time, downsampled by ``avg_pool2d`` (what :func:`msdepth.losses.ssim_kernels.ms_ssim_levels` batches)."""
    values = []
    for level in range(levels):
        if padding == "valid" and min(x.shape[-2:]) < kernel_size:
            raise ValueError(
                f"ms_ssim: level {level} is {tuple(x.shape[-2:])} px, smaller than the "
                f"{kernel_size} px window; use padding='same' or fewer levels"
            )
        cs, full = _reference_ssim_terms(x, y, kernel_size, window, sigma, padding)
        values.append((full if level == levels - 1 else cs).mean((2, 3)))
        h, w = x.shape[-2:]
        x = F.avg_pool2d(x, kernel_size=2, padding=[h % 2, w % 2])
        y = F.avg_pool2d(y, kernel_size=2, padding=[h % 2, w % 2])
    return torch.stack(values)


# ----------------------------------------------------------------------------- SSIM


def ssim(
    x: Tensor,
    y: Tensor,
    kernel_size: int = 3,
    padding: Literal["valid", "reflect"] = "valid",
    window: Window = "box",
    sigma: float = 1.5,
    implementation: Implementation = "fast",
) -> Tensor:
    """Per-pixel SSIM map between images in [0, 1].

    Statistics come from a ``kernel_size`` window, stride 1 (``"box"`` = average pooling, as in
    Monodepth; ``"gaussian"`` with ``sigma``, as in Wang et al. and pytorch-msssim).

    Args:
        x: (B, C, H, W) image in [0, 1].
        y: (B, C, H, W) image in [0, 1], the shape of ``x``.
        kernel_size: odd window size in px.
        padding: ``"valid"`` (Monodepth) returns (B, C, H-k+1, W-k+1); ``"reflect"`` (Monodepth2)
            reflection-pads by k//2 first and returns the full (B, C, H, W).
        window: ``"box"`` or ``"gaussian"``.
        sigma: the Gaussian window's standard deviation in px.
        implementation: ``"fast"`` (:mod:`msdepth.losses.ssim_kernels`) or ``"reference"``
            (:func:`_reference_ssim_terms`); the same values up to rounding.

    Returns:
        The SSIM map; 1 where the images agree locally, can be negative for anticorrelated ones.

    Raises:
        ValueError: shapes that differ or are not 4-D, an even or non-positive ``kernel_size``, an
            unknown ``padding`` or ``implementation``, or an image smaller than the window.

    Example:
        >>> import torch
        >>> x = torch.linspace(0, 1, 64).reshape(1, 1, 8, 8)
        >>> ssim(x, x).shape  # valid padding: 8 - 3 + 1 px a side
        torch.Size([1, 1, 6, 6])
        >>> round(ssim(x, x).mean().item(), 4), round(ssim(x, 1 - x).mean().item(), 4)
        (1.0, -0.6548)
    """
    _check_pair("ssim", x, y)
    _check_kernel("ssim", kernel_size)
    _check_implementation("ssim", implementation)
    if padding == "reflect":
        pad = kernel_size // 2
        x = F.pad(x, (pad, pad, pad, pad), mode="reflect")
        y = F.pad(y, (pad, pad, pad, pad), mode="reflect")
    elif padding != "valid":
        raise ValueError(f"ssim: padding must be 'valid' or 'reflect', got {padding!r}")
    if min(x.shape[-2:]) < kernel_size:
        raise ValueError(f"ssim: image {tuple(x.shape[-2:])} is smaller than the {kernel_size} px window")
    if implementation == "reference":
        return _reference_ssim_terms(x, y, kernel_size, window, sigma, "valid")[1]
    return kernels.ssim_terms(x, y, kernel_size, window, sigma, "valid", luminance=True)[1]


# ----------------------------------------------------------------------------- MS-SSIM


def level_weights(weights: str | Tensor | Sequence[float], levels: int, like: Tensor) -> Tensor:
    """Resolve an MS-SSIM weight spec to a 1-D tensor of ``levels`` weights (fine -> coarse).

    ``"wang"``: Wang et al.'s five weights truncated to ``levels`` and renormalised to sum 1
    (for 5 levels exactly Wang's list, whose rounded values sum to 1.0001); ``"equal"``:
    1/levels each; a tensor or sequence is used as given (e.g. the output of
    :class:`LearnedLevelWeights`, keeping its gradient).
    """
    if isinstance(weights, str):
        if weights == "wang":
            if not 1 <= levels <= len(WANG_WEIGHTS):
                raise ValueError(f"ms_ssim: 'wang' weights exist for 1..5 levels, got {levels}")
            w = like.new_tensor(WANG_WEIGHTS[:levels])
            # The published five sum to 1.0001 (rounding); keep them verbatim so 5 levels match
            # Wang et al. and pytorch-msssim exactly, renormalise only a truncated list.
            return w if levels == len(WANG_WEIGHTS) else w / w.sum()
        if weights == "equal":
            return like.new_full((levels,), 1.0 / levels)
        raise ValueError(f"ms_ssim: weights must be 'wang', 'equal' or a tensor, got {weights!r}")
    w = weights if isinstance(weights, Tensor) else like.new_tensor(list(weights))
    if w.shape != (levels,):
        raise ValueError(f"ms_ssim: expected {levels} level weights, got shape {tuple(w.shape)}")
    return w.to(like.dtype)


def ms_ssim(
    x: Tensor,
    y: Tensor,
    kernel_size: int = 3,
    levels: int = 4,
    weights: str | Tensor | Sequence[float] = "wang",
    window: Window = "box",
    sigma: float = 1.5,
    padding: Literal["same", "valid"] = "same",
    implementation: Implementation = "fast",
) -> Tensor:
    """Multi-scale SSIM per image, (B,), for images in [0, 1].

    At each of ``levels`` scales the window statistics give a contrast-structure term ``cs``;
    the luminance term is used only at the coarsest scale (so the last level is full SSIM).
    Between scales both images are halved by 2x2 average pooling (padding = size % 2, exactly as
    pytorch-msssim). Each level's map is averaged over space per image and channel, and
    ``MS-SSIM = prod_l cs_l ** w_l · ssim_L ** w_L`` is then averaged over channels; with
    ``window="gaussian", kernel_size=11, sigma=1.5, levels=5, padding="valid", weights="wang"``
    this is ``pytorch_msssim.ms_ssim(x, y, data_range=1, size_average=False)``.

    Differences from pytorch-msssim, both for training: per-level values are clamped to
    ``1e-6`` instead of relu'd, so ``cs ** w`` never has an unbounded gradient when ``cs`` is
    zero, negative (anticorrelated patches) or barely positive; and ``padding="same"`` (the
    default, dissertation 3.5) lets any image of at least 1 px be used, however small against
    the window.

    Args:
        x: (B, C, H, W) image in [0, 1].
        y: (B, C, H, W) image in [0, 1], the shape of ``x``.
        kernel_size: odd window size (dissertation: 3, 5, 7 or 11).
        levels: number of scales.
        weights: ``"wang"``, ``"equal"``, or a 1-D tensor of per-level weights (fine -> coarse).
        window: ``"box"`` (average pooling) or ``"gaussian"`` (separable, ``sigma``).
        sigma: the Gaussian window's standard deviation in px.
        padding: ``"same"`` (keep size, average only in-image pixels) or ``"valid"``.
        implementation: ``"fast"`` or ``"reference"``, as for :func:`ssim`.

    Returns:
        (B,) MS-SSIM per image: 1 for identical images.

    Raises:
        ValueError: as :func:`ssim`, and for bad ``levels``, ``weights`` or ``window``.

    Example:
        >>> import torch
        >>> x = torch.linspace(0, 1, 256).reshape(1, 1, 16, 16)
        >>> round(ms_ssim(x, x).item(), 4), round(ms_ssim(x, 0.5 * x).item(), 4)
        (1.0, 0.763)
    """
    _check_pair("ms_ssim", x, y)
    return ms_ssim_pyramid([x], [y], kernel_size, levels, weights, window, sigma, padding, implementation)[0]


def ms_ssim_pyramid(
    xs: Sequence[Tensor],
    ys: Sequence[Tensor],
    kernel_size: int = 3,
    levels: int = 4,
    weights: str | Tensor | Sequence[float] = "wang",
    window: Window = "box",
    sigma: float = 1.5,
    padding: Literal["same", "valid"] = "same",
    implementation: Implementation = "fast",
) -> Tensor:
    """:func:`ms_ssim` of every pair ``(xs[i], ys[i])`` (all B images of C channels), as (len(xs), B).

    Made for a scale pyramid (pair i half the size of pair i - 1, as in
    :class:`msdepth.losses.monodepth.MonodepthLoss`): the fast implementation sends same-sized
    levels of all pairs through the kernels together (:func:`msdepth.losses.ssim_kernels.ms_ssim_levels`);
    per image the arithmetic is that of separate :func:`ms_ssim` calls, and pairs of other sizes
    work too.
    """
    n = len(xs)
    if n == 0 or len(ys) != n:
        raise ValueError(f"ms_ssim: expected as many estimates as targets (>= 1), got {n} and {len(ys)}")
    for x, y in zip(xs, ys, strict=True):
        _check_pair("ms_ssim", x, y)
        if x.shape[:2] != xs[0].shape[:2]:
            raise ValueError(
                f"ms_ssim: every pair needs the same (B, C), got {tuple(xs[0].shape[:2])} "
                f"and {tuple(x.shape[:2])}"
            )
    _check_kernel("ms_ssim", kernel_size)
    _check_implementation("ms_ssim", implementation)
    if levels < 1:
        raise ValueError(f"ms_ssim: levels must be >= 1, got {levels}")
    if padding not in ("same", "valid"):
        raise ValueError(f"ms_ssim: padding must be 'same' or 'valid', got {padding!r}")
    if window not in ("box", "gaussian"):
        raise ValueError(f"ms_ssim: window must be 'box' or 'gaussian', got {window!r}")
    w = level_weights(weights, levels, xs[0])
    if implementation == "fast":
        stacked = kernels.ms_ssim_levels(xs, ys, kernel_size, levels, window, sigma, padding)
    else:
        stacked = torch.stack(
            [
                _reference_ms_ssim_levels(x, y, kernel_size, levels, window, sigma, padding)
                for x, y in zip(xs, ys, strict=True)
            ]
        )
    stacked = stacked.clamp(min=_MS_SSIM_EPS)  # (n, levels, B, C)
    return torch.prod(stacked ** w.view(1, -1, 1, 1), dim=1).mean(dim=-1)


class LearnedLevelWeights(nn.Module):
    """Trainable MS-SSIM level weights: softmax of free logits, so always positive, summing to 1.

    A softmax (rather than raw weights) means the optimiser cannot zero or negate a level to
    shortcut the loss. Initialised to equal weights.
    """

    def __init__(self, levels: int) -> None:
        super().__init__()
        if levels < 1:
            raise ValueError(f"LearnedLevelWeights: levels must be >= 1, got {levels}")
        self.logits = nn.Parameter(torch.zeros(levels))

    def forward(self) -> Tensor:
        """The current (levels,) weights."""
        return torch.softmax(self.logits, dim=0)
