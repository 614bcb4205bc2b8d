"""Monodepth's self-supervised training loss, with a registered appearance term (SSIM, MS-SSIM, ...).

Functional core: :func:`ssim`, :func:`ms_ssim`, :func:`appearance_loss`, :func:`smoothness_loss`,
:func:`lr_consistency_loss`, :func:`reconstruct` and :func:`scale_pyramid` are plain functions on
tensors. SSIM and MS-SSIM run on the fast kernels of :mod:`msdepth.losses.ssim_kernels` by default, or with
``implementation="reference"`` on the written-out autograd formula here
(:func:`reference_ssim_terms`), which the fast kernels are tested against. Modules hold state:
:class:`LearnedLevelWeights` (trainable MS-SSIM level weights), :class:`AppearanceTerm` (the base
of the appearance terms in :mod:`msdepth.losses.appearance`) and :class:`MonodepthLoss` (the configured
multi-scale loss).

Images are (B, C, H, W) in [0, 1]; disparities are (B, 1, H, W) fractions of image width.
"""

from __future__ import annotations

from typing import Callable, Literal, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from msdepth.config.params import LossConfig
from msdepth.geometry.warp import PaddingMode, warp
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


def reference_ssim_terms(
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
        cs, full = reference_ssim_terms(x, y, kernel_size, window, sigma, padding)
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
            (:func:`reference_ssim_terms`); the same values up to rounding.

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
        return reference_ssim_terms(x, y, kernel_size, window, sigma, "valid")[1]
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

    Made for a scale pyramid (pair i half the size of pair i - 1, as in :class:`MonodepthLoss`):
    the fast implementation sends same-sized levels of all pairs through the kernels together
    (:func:`msdepth.losses.ssim_kernels.ms_ssim_levels`); per image the arithmetic is that of separate
    :func:`ms_ssim` calls, and pairs of other sizes work too.
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


# ----------------------------------------------------------------------------- loss terms


def appearance_loss(
    estimate: Tensor, target: Tensor, alpha: float = 0.85, similarity: Similarity = ssim
) -> Tensor:
    """Photometric reconstruction loss ``α·mean(clip((1-S)/2, 0, 1)) + (1-α)·mean|Î - I|``.

    ``S = similarity(estimate, target)`` is an SSIM map or a per-image MS-SSIM; the mean runs
    over whatever it returns. Default: Monodepth's 3x3 box SSIM with valid padding.
    """
    return similarity_appearance_loss(similarity(estimate, target), estimate, target, alpha)


def similarity_appearance_loss(similarity: Tensor, estimate: Tensor, target: Tensor, alpha: float) -> Tensor:
    """:func:`appearance_loss` given the similarity ``S`` already computed."""
    dissimilarity = ((1 - similarity) / 2).clamp(0, 1)
    return alpha * dissimilarity.mean() + (1 - alpha) * (estimate - target).abs().mean()


def smoothness_loss(disp: Tensor, image: Tensor) -> Tensor:
    """Edge-aware smoothness ``mean|∂x d|·e^{-mean_c|∂x I|} + mean|∂y d|·e^{-mean_c|∂y I|}``.

    Disparity gradients are down-weighted where the image has edges (depth may jump there).
    Both directions are applied: Monodepth's TensorFlow code builds ``[x terms] + [y terms]`` as a
    Python list and then sums only its first four entries, so it only ever uses the x term — a
    known bug we do not reproduce. The caller weights this by ``smoothness_weight / 2**scale``.
    """
    if disp.dim() != 4 or disp.shape[1] != 1 or disp.shape[-2:] != image.shape[-2:]:
        raise ValueError(
            f"smoothness_loss: expected disp (B, 1, H, W) matching image {tuple(image.shape)}, "
            f"got {tuple(disp.shape)}"
        )
    d_dx = (disp[..., :, :-1] - disp[..., :, 1:]).abs()
    d_dy = (disp[..., :-1, :] - disp[..., 1:, :]).abs()
    w_x = torch.exp(-(image[..., :, :-1] - image[..., :, 1:]).abs().mean(1, keepdim=True))
    w_y = torch.exp(-(image[..., :-1, :] - image[..., 1:, :]).abs().mean(1, keepdim=True))
    return (d_dx * w_x).mean() + (d_dy * w_y).mean()


def lr_consistency_loss(
    disp_left: Tensor, disp_right: Tensor, padding_mode: PaddingMode = "border"
) -> Tensor:
    """Left-right disparity consistency ``mean|d_l - warp(d_r, -d_l)| + mean|d_r - warp(d_l, d_r)|``.

    Each view's disparity should equal the other view's disparity seen through it.
    """
    right_to_left = warp(disp_right, -disp_left, padding_mode)
    left_to_right = warp(disp_left, disp_right, padding_mode)
    return (disp_left - right_to_left).abs().mean() + (disp_right - left_to_right).abs().mean()


def reconstruct(
    left: Tensor, right: Tensor, disp_left: Tensor, disp_right: Tensor, padding_mode: PaddingMode = "border"
) -> Tensor:
    """Both views rebuilt from the other, as one (2B, C, H, W) batch (left then right): the left
    from the right with ``-disp_left``, the right from the left with ``+disp_right``.

    What the appearance term compares with ``torch.cat((left, right))`` at every scale of
    :class:`MonodepthLoss`; also the cost curves' reconstruction (:mod:`msdepth.optimum.solver`).
    """
    sources, shifts = torch.cat((right, left)), torch.cat((-disp_left, disp_right))
    return warp(sources, shifts, padding_mode)


def scale_pyramid(image: Tensor, num_scales: int = 4) -> list[Tensor]:
    """``[image, image/2, ..., image/2**(num_scales-1)]`` by area (average) downsampling.

    Scale s is (H // 2**s, W // 2**s), the size of the network's disparity at that scale.
    """
    h, w = image.shape[-2:]
    pyramid = [image]
    for s in range(1, num_scales):
        size = (h >> s, w >> s)
        if min(size) < 1:
            raise ValueError(f"scale_pyramid: {h}x{w} image has no scale {s} (would be {size})")
        pyramid.append(F.interpolate(image, size=size, mode="area"))
    return pyramid


# ----------------------------------------------------------------------------- module


class AppearanceTerm(nn.Module):
    """Base of the appearance terms (:mod:`msdepth.losses.appearance`): the photometric loss of each scale's
    reconstruction against its target.

    A term keeps any state (e.g. :class:`LearnedLevelWeights`) in child modules, which
    :class:`MonodepthLoss` registers under their own names: its state dict reads
    ``level_weights.logits`` whichever term holds them.
    """

    def forward(self, estimates: Sequence[Tensor], targets: Sequence[Tensor]) -> list[Tensor]:
        """Per scale (fine -> coarse), the scalar loss of ``estimates[s]`` against ``targets[s]``,
        a mean over the batch."""
        raise NotImplementedError


class MonodepthLoss(nn.Module):
    """Monodepth's multi-scale stereo loss (appearance + smoothness + left-right consistency).

    ``appearance`` is the variant's term (:func:`msdepth.losses.appearance.build_appearance`); its child
    modules (trainable weights) are this module's, so they reach the optimiser via
    ``.parameters()`` and the checkpoint via ``.state_dict()``.
    """

    def __init__(self, loss_cfg: LossConfig, appearance: AppearanceTerm) -> None:
        super().__init__()
        if not isinstance(appearance, AppearanceTerm):
            raise TypeError(f"MonodepthLoss: appearance must be an AppearanceTerm, got {type(appearance)}")
        if any(True for _ in appearance.parameters(recurse=False)) or any(
            True for _ in appearance.buffers(recurse=False)
        ):
            raise ValueError("MonodepthLoss: an appearance term keeps its state in child modules")
        self.loss_cfg = loss_cfg
        # Not a submodule (its children are registered directly below): the state dict keeps the
        # names checkpoints were written with.
        self.__dict__["appearance"] = appearance
        for name, child in appearance.named_children():
            self.add_module(name, child)

    def forward(self, disps: Sequence[Tensor], left: Tensor, right: Tensor) -> dict[str, Tensor]:
        """Loss terms for one batch.

        Args:
            disps: per scale (fine -> coarse), (B, 2, H/2**s, W/2**s); channel 0 is the left
                disparity, 1 the right, as fractions of width.
            left, right: the (B, 3, H, W) stereo pair.

        Returns:
            ``"appearance"``, ``"smoothness"`` (sum of per-scale terms / 2**s) and
            ``"lr_consistency"``, each summed over scales and both views, and ``"total"`` =
            appearance + smoothness_weight·smoothness + lr_weight·lr_consistency.
        """
        cfg = self.loss_cfg
        # Both views in one batch (left then right): half the warp, pooling and similarity calls,
        # whose cost at the small scales is mostly per-call overhead.
        batch = left.shape[0]
        targets = scale_pyramid(torch.cat((left, right)), len(disps))
        estimates = []
        smoothness = lr = left.new_zeros(())
        for s, (disp, target) in enumerate(zip(disps, targets, strict=True)):
            if disp.dim() != 4 or disp.shape[1] != 2 or disp.shape[-2:] != target.shape[-2:]:
                raise ValueError(
                    f"MonodepthLoss: scale {s} disparity must be (B, 2, {target.shape[-2]}, "
                    f"{target.shape[-1]}), got {tuple(disp.shape)}"
                )
            left_s, right_s = target[:batch], target[batch:]
            disp_left, disp_right = disp[:, :1], disp[:, 1:]
            estimates.append(reconstruct(left_s, right_s, disp_left, disp_right, cfg.padding_mode))
            smooth_s = smoothness_loss(disp_left, left_s) + smoothness_loss(disp_right, right_s)
            smoothness = smoothness + smooth_s / 2**s
            lr = lr + lr_consistency_loss(disp_left, disp_right, cfg.padding_mode)
        appearance = left.new_zeros(())
        for term in self.appearance(estimates, targets):
            # Each view's term is a mean over equally many values, so their sum is 2x the joint mean.
            appearance = appearance + 2 * term
        total = appearance + cfg.smoothness_weight * smoothness + cfg.lr_weight * lr
        return {"total": total, "appearance": appearance, "smoothness": smoothness, "lr_consistency": lr}
