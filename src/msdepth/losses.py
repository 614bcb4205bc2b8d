"""Monodepth's self-supervised training loss, with SSIM or MS-SSIM as the appearance term.

Functional core: :func:`ssim`, :func:`ms_ssim`, :func:`appearance_loss`, :func:`smoothness_loss`,
:func:`lr_consistency_loss` and :func:`scale_pyramid` are plain functions on tensors. Two thin
modules hold state: :class:`LearnedLevelWeights` (trainable MS-SSIM level weights) and
:class:`MonodepthLoss` (the configured multi-scale loss).

Images are (B, C, H, W) in [0, 1]; disparities are (B, 1, H, W) fractions of image width.
"""

from __future__ import annotations

from typing import Callable, Literal, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .config import LossConfig, MSSSIMConfig, SSIMConfig
from .warp import PaddingMode, warp

Similarity = Callable[[Tensor, Tensor], Tensor]
"""``similarity(x, y)``: an SSIM map (B, C, H', W') or a per-image MS-SSIM (B,); 1 = identical."""

Window = Literal["box", "gaussian"]

C1 = 0.01**2  # (K1 · data_range)², data_range = 1
C2 = 0.03**2
# Wang, Simoncelli & Bovik (2003), 5 scales fine -> coarse.
WANG_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
# Floor for per-level MS-SSIM values before the power: d(x**w)/dx = w·x**(w-1) is unbounded as
# x -> 0+ for w < 1, so relu'd values just above 0 can overflow to inf/NaN gradients; the floor
# bounds it (about w·1e6) and makes negative contrast-structure a flat, finite region.
_MS_SSIM_EPS = 1e-6


# ----------------------------------------------------------------------------- windows


def _gaussian_1d(kernel_size: int, sigma: float, like: Tensor) -> Tensor:
    """Normalised 1-D Gaussian of ``kernel_size`` taps (same as pytorch-msssim's window)."""
    coords = torch.arange(kernel_size, dtype=like.dtype, device=like.device) - kernel_size // 2
    g = torch.exp(-(coords**2) / (2 * sigma**2))
    return g / g.sum()


def _window_mean(
    x: Tensor, kernel_size: int, window: Window, sigma: float, padding: Literal["valid", "same"]
) -> Tensor:
    """Local (weighted) mean of every channel of ``x`` over a ``kernel_size`` window, stride 1.

    ``"valid"`` keeps only windows fully inside the image. ``"same"`` keeps the input size and
    averages only over the pixels that exist (zero padding renormalised by the window mass), so
    it works on images of any size, even smaller than the window.
    """
    pad = kernel_size // 2 if padding == "same" else 0
    if window == "box":
        # Same as avg_pool2d(x, k, 1, pad, count_include_pad=False): border windows average
        # the in-image pixels only. Zero-pad, box-sum, divide by the in-image pixel count.
        if pad:
            h, w = x.shape[-2:]
            x = F.pad(x, (pad, pad, pad, pad))
            count_h = _box_sum(F.pad(x.new_ones(1, 1, h, 1), (0, 0, pad, pad)), kernel_size, (-2,))
            count_w = _box_sum(F.pad(x.new_ones(1, 1, 1, w), (pad, pad)), kernel_size, (-1,))
            return _box_sum(x, kernel_size) / (count_h * count_w)
        return _box_sum(x, kernel_size) / kernel_size**2
    g = _gaussian_1d(kernel_size, sigma, x)
    out = _separable_conv(x, g, pad)
    if pad:
        # Divide by the window mass that fell inside the image (1 away from the borders).
        out = out / _separable_conv(x.new_ones(1, 1, *x.shape[2:]), g, pad)
    return out


def _shifted_sum(x: Tensor, k: int, dims: tuple[int, ...]) -> Tensor:
    """Sum of the ``k`` shifted views of ``x`` along each of ``dims`` (a valid box sum)."""
    for dim in dims:
        n = x.shape[dim] - k + 1
        acc = x.narrow(dim, 0, n)
        for i in range(1, k):
            acc = acc + x.narrow(dim, i, n)
        x = acc
    return x


class _BoxSum(torch.autograd.Function):
    """Valid box sum whose backward is the "full" box sum of the gradient.

    Autograd through the shifted views would zero-fill and scatter one full-size buffer per
    view; the adjoint of a valid box sum is the same sum over the gradient zero-padded by k-1.
    """

    @staticmethod
    def forward(ctx, x: Tensor, k: int, dims: tuple[int, ...]) -> Tensor:  # type: ignore[override]
        ctx.k, ctx.dims = k, dims
        return _shifted_sum(x, k, dims)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: Tensor):  # type: ignore[override]
        k, pad = ctx.k, [0, 0, 0, 0]
        for dim in ctx.dims:
            pad[2 * (-1 - dim)] = pad[2 * (-1 - dim) + 1] = k - 1  # F.pad lists the last dim first
        return _shifted_sum(F.pad(grad, pad), k, ctx.dims), None, None


def _box_sum(x: Tensor, kernel_size: int, dims: tuple[int, ...] = (-1, -2)) -> Tensor:
    """Sum over every ``kernel_size`` window along each of ``dims`` (-1 and/or -2), stride 1, no padding.

    Measured on CPU (benchmarks/loss.py), PyTorch's stride-1 ``avg_pool2d`` and its backward
    cost ~k² per pixel and dominated the training step: summing k shifted views per axis is
    faster for k <= 7, and a depthwise 1-D convolution per axis beyond.
    """
    if kernel_size > 7 and dims == (-1, -2):
        return _separable_conv(x, x.new_ones(kernel_size), 0)
    return _BoxSum.apply(x, kernel_size, dims)


def _separable_conv(x: Tensor, g: Tensor, pad: int) -> Tensor:
    """Filter every channel of ``x`` with the 1-D kernel ``g`` along H then W, zero-padded by ``pad``."""
    channels, k = x.shape[1], g.numel()
    x = F.conv2d(x, g.view(1, 1, k, 1).expand(channels, 1, k, 1), padding=(pad, 0), groups=channels)
    return F.conv2d(x, g.view(1, 1, 1, k).expand(channels, 1, 1, k), padding=(0, pad), groups=channels)


def _moments(
    x: Tensor, y: Tensor, window_mean: Callable[[Tensor], Tensor]
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Local means, variances and covariance of ``x`` and ``y`` from ONE pooled pass."""
    c = x.shape[1]
    # Stacking along channels lets one pooling call serve all five statistics.
    pooled = window_mean(torch.cat((x, y, x * x, y * y, x * y), dim=1))
    mu_x, mu_y, xx, yy, xy = pooled.split(c, dim=1)
    return mu_x, mu_y, xx - mu_x * mu_x, yy - mu_y * mu_y, xy - mu_x * mu_y


def _luminance_and_cs(x: Tensor, y: Tensor, window_mean: Callable[[Tensor], Tensor]) -> tuple[Tensor, Tensor]:
    """Per-pixel luminance term and contrast-structure term of SSIM."""
    mu_x, mu_y, var_x, var_y, cov = _moments(x, y, window_mean)
    luminance = (2 * mu_x * mu_y + C1) / (mu_x * mu_x + mu_y * mu_y + C1)
    cs = (2 * cov + C2) / (var_x + var_y + C2)
    return luminance, cs


def _check_pair(name: str, x: Tensor, y: Tensor) -> None:
    if x.dim() != 4 or x.shape != y.shape:
        raise ValueError(
            f"{name}: expected two (B, C, H, W) tensors of the same shape, "
            f"got {tuple(x.shape)} and {tuple(y.shape)}"
        )


def _check_kernel(name: str, kernel_size: int) -> None:
    if kernel_size < 1 or kernel_size % 2 != 1:
        raise ValueError(f"{name}: kernel_size must be a positive odd integer, got {kernel_size}")


# ----------------------------------------------------------------------------- SSIM


def ssim(
    x: Tensor,
    y: Tensor,
    kernel_size: int = 3,
    padding: Literal["valid", "reflect"] = "valid",
    window: Window = "box",
    sigma: float = 1.5,
) -> Tensor:
    """Per-pixel SSIM map between images in [0, 1].

    Statistics come from a ``kernel_size`` window, stride 1 (``"box"`` = average pooling, as in
    Monodepth; ``"gaussian"`` with ``sigma``, as in Wang et al. and pytorch-msssim).

    Args:
        padding: ``"valid"`` (Monodepth) returns (B, C, H-k+1, W-k+1); ``"reflect"`` (Monodepth2)
            reflection-pads by k//2 first and returns the full (B, C, H, W).

    Returns:
        The SSIM map; 1 where the images agree locally, can be negative for anticorrelated ones.
    """
    _check_pair("ssim", x, y)
    _check_kernel("ssim", kernel_size)
    if padding == "reflect":
        pad = kernel_size // 2
        x = F.pad(x, (pad, pad, pad, pad), mode="reflect")
        y = F.pad(y, (pad, pad, pad, pad), mode="reflect")
    elif padding != "valid":
        raise ValueError(f"ssim: padding must be 'valid' or 'reflect', got {padding!r}")
    if min(x.shape[-2:]) < kernel_size:
        raise ValueError(f"ssim: image {tuple(x.shape[-2:])} is smaller than the {kernel_size} px window")
    luminance, cs = _luminance_and_cs(
        x, y, lambda t: _window_mean(t, kernel_size, window, sigma, padding="valid")
    )
    return luminance * cs


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
        kernel_size: odd window size (dissertation: 3, 5, 7 or 11).
        levels: number of scales.
        weights: ``"wang"``, ``"equal"``, or a 1-D tensor of per-level weights (fine -> coarse).
        window: ``"box"`` (average pooling) or ``"gaussian"`` (separable, ``sigma``).
        padding: ``"same"`` (keep size, average only in-image pixels) or ``"valid"``.
    """
    _check_pair("ms_ssim", x, y)
    _check_kernel("ms_ssim", kernel_size)
    if levels < 1:
        raise ValueError(f"ms_ssim: levels must be >= 1, got {levels}")
    if padding not in ("same", "valid"):
        raise ValueError(f"ms_ssim: padding must be 'same' or 'valid', got {padding!r}")
    if window not in ("box", "gaussian"):
        raise ValueError(f"ms_ssim: window must be 'box' or 'gaussian', got {window!r}")
    w = level_weights(weights, levels, x)

    def window_mean(t: Tensor) -> Tensor:
        return _window_mean(t, kernel_size, window, sigma, padding)

    values = []
    for level in range(levels):
        if padding == "valid" and min(x.shape[-2:]) < kernel_size:
            raise ValueError(
                f"ms_ssim: level {level} is {tuple(x.shape[-2:])} px, smaller than the "
                f"{kernel_size} px window; use padding='same' or fewer levels"
            )
        luminance, cs = _luminance_and_cs(x, y, window_mean)
        if level < levels - 1:
            values.append(cs.flatten(2).mean(-1))  # (B, C)
            # pytorch-msssim's downsampling, kept verbatim: odd sizes pad 1 px and (default
            # count_include_pad) halve that edge row/column. Same for x and y, so x == y stays 1.
            pad = [s % 2 for s in x.shape[-2:]]
            x = F.avg_pool2d(x, kernel_size=2, padding=pad)
            y = F.avg_pool2d(y, kernel_size=2, padding=pad)
        else:
            values.append((luminance * cs).flatten(2).mean(-1))
    stacked = torch.stack(values, dim=0).clamp(min=_MS_SSIM_EPS)  # (levels, B, C)
    return torch.prod(stacked ** w.view(-1, 1, 1), dim=0).mean(dim=1)


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


def make_similarity(
    appearance: Literal["ssim", "msssim"],
    ssim_cfg: SSIMConfig,
    msssim_cfg: MSSSIMConfig,
    learned_weights: LearnedLevelWeights | None = None,
) -> Similarity:
    """The configured similarity function ``(x, y) -> SSIM map or per-image MS-SSIM``.

    With ``msssim_cfg.weights == "learned"``, ``learned_weights`` must be given; it is called on
    every use so the current parameter values (and their gradient) are used.
    """
    if appearance == "ssim":
        return lambda x, y: ssim(x, y, kernel_size=ssim_cfg.kernel_size, padding=ssim_cfg.padding)
    if appearance != "msssim":
        raise ValueError(f"appearance must be 'ssim' or 'msssim', got {appearance!r}")
    if msssim_cfg.weights == "learned":
        if learned_weights is None:
            raise ValueError("msssim weights 'learned' need a LearnedLevelWeights module")

        def learned(x: Tensor, y: Tensor) -> Tensor:
            return ms_ssim(x, y, msssim_cfg.kernel_size, msssim_cfg.levels, weights=learned_weights())

        return learned
    return lambda x, y: ms_ssim(x, y, msssim_cfg.kernel_size, msssim_cfg.levels, weights=msssim_cfg.weights)


def appearance_loss(
    estimate: Tensor, target: Tensor, alpha: float = 0.85, similarity: Similarity = ssim
) -> Tensor:
    """Photometric reconstruction loss ``α·mean(clip((1-S)/2, 0, 1)) + (1-α)·mean|Î - I|``.

    ``S = similarity(estimate, target)`` is an SSIM map or a per-image MS-SSIM; the mean runs
    over whatever it returns. Default: Monodepth's 3x3 box SSIM with valid padding.
    """
    dissimilarity = ((1 - similarity(estimate, target)) / 2).clamp(0, 1)
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


class MonodepthLoss(nn.Module):
    """Monodepth's multi-scale stereo loss (appearance + smoothness + left-right consistency).

    Holds :class:`LearnedLevelWeights` as ``level_weights`` when ``msssim_cfg.weights ==
    "learned"`` (else ``None``), so those parameters reach the optimiser via ``.parameters()``.
    """

    def __init__(
        self,
        loss_cfg: LossConfig,
        appearance: Literal["ssim", "msssim"],
        ssim_cfg: SSIMConfig,
        msssim_cfg: MSSSIMConfig,
    ) -> None:
        super().__init__()
        if appearance not in ("ssim", "msssim"):
            raise ValueError(f"MonodepthLoss: appearance must be 'ssim' or 'msssim', got {appearance!r}")
        self.loss_cfg, self.appearance = loss_cfg, appearance
        self.ssim_cfg, self.msssim_cfg = ssim_cfg, msssim_cfg
        learned = appearance == "msssim" and msssim_cfg.weights == "learned"
        self.level_weights = LearnedLevelWeights(msssim_cfg.levels) if learned else None

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
        # Built per call (cheap) rather than stored, so copies of this module never keep a
        # closure over another copy's level weights.
        similarity = make_similarity(self.appearance, self.ssim_cfg, self.msssim_cfg, self.level_weights)
        lefts = scale_pyramid(left, len(disps))
        rights = scale_pyramid(right, len(disps))
        appearance = smoothness = lr = left.new_zeros(())
        for s, (disp, left_s, right_s) in enumerate(zip(disps, lefts, rights)):
            if disp.dim() != 4 or disp.shape[1] != 2 or disp.shape[-2:] != left_s.shape[-2:]:
                raise ValueError(
                    f"MonodepthLoss: scale {s} disparity must be (B, 2, {left_s.shape[-2]}, "
                    f"{left_s.shape[-1]}), got {tuple(disp.shape)}"
                )
            disp_left, disp_right = disp[:, :1], disp[:, 1:]
            left_est = warp(right_s, -disp_left, cfg.padding_mode)
            right_est = warp(left_s, disp_right, cfg.padding_mode)
            appearance = appearance + appearance_loss(left_est, left_s, cfg.alpha, similarity)
            appearance = appearance + appearance_loss(right_est, right_s, cfg.alpha, similarity)
            smooth_s = smoothness_loss(disp_left, left_s) + smoothness_loss(disp_right, right_s)
            smoothness = smoothness + smooth_s / 2**s
            lr = lr + lr_consistency_loss(disp_left, disp_right, cfg.padding_mode)
        total = appearance + cfg.smoothness_weight * smoothness + cfg.lr_weight * lr
        return {"total": total, "appearance": appearance, "smoothness": smoothness, "lr_consistency": lr}
