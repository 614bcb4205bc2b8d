"""Monodepth's self-supervised training loss, with a registered appearance term (SSIM, MS-SSIM, ...).

Functional core: :func:`appearance_loss`, :func:`smoothness_loss`, :func:`_lr_consistency_loss`,
:func:`reconstruct` and :func:`scale_pyramid` are plain functions on tensors; the similarities
they compare with (SSIM, MS-SSIM) are :mod:`msdepth.losses.ssim`'s. Modules hold state:
:class:`AppearanceTerm` (the base of the appearance terms in :mod:`msdepth.losses.appearance`) and
:class:`MonodepthLoss` (the configured multi-scale loss).

Images are (B, C, H, W) in [0, 1]; disparities are (B, 1, H, W) fractions of image width.
"""

from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from msdepth.config.params import LossConfig
from msdepth.geometry.warp import PaddingMode, warp
from msdepth.losses.ssim import Similarity, ssim

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


def _lr_consistency_loss(
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

    A term keeps any state (e.g. :class:`msdepth.losses.ssim.LearnedLevelWeights`) in child
    modules, which :class:`MonodepthLoss` registers under their own names: its state dict reads
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
            appearance + smoothness_weight·smoothness + lr_weight·lr_consistency. With
            ``loss.full_resolution`` the appearance and left-right terms of every scale are
            computed at (H, W) on its bilinearly upsampled disparity.
        """
        cfg = self.loss_cfg
        # Both views in one batch (left then right): half the warp, pooling and similarity calls,
        # whose cost at the small scales is mostly per-call overhead.
        batch = left.shape[0]
        pyramid = scale_pyramid(torch.cat((left, right)), len(disps))
        targets = [pyramid[0]] * len(disps) if cfg.full_resolution else pyramid
        estimates = []
        smoothness = lr = left.new_zeros(())
        for s, (disp, image) in enumerate(zip(disps, pyramid, strict=True)):
            if disp.dim() != 4 or disp.shape[1] != 2 or disp.shape[-2:] != image.shape[-2:]:
                raise ValueError(
                    f"MonodepthLoss: scale {s} disparity must be (B, 2, {image.shape[-2]}, "
                    f"{image.shape[-1]}), got {tuple(disp.shape)}"
                )
            left_s, right_s, target = image[:batch], image[batch:], targets[s]
            disp_left, disp_right = disp[:, :1], disp[:, 1:]
            warp_left, warp_right = disp_left, disp_right
            if cfg.full_resolution and s > 0:  # Monodepth2: warp at the input size
                full = F.interpolate(disp, size=left.shape[-2:], mode="bilinear", align_corners=False)
                warp_left, warp_right = full[:, :1], full[:, 1:]
            estimates.append(
                reconstruct(target[:batch], target[batch:], warp_left, warp_right, cfg.padding_mode)
            )
            smooth_s = smoothness_loss(disp_left, left_s) + smoothness_loss(disp_right, right_s)
            smoothness = smoothness + smooth_s / 2**s
            lr = lr + _lr_consistency_loss(warp_left, warp_right, cfg.padding_mode)
        appearance = left.new_zeros(())
        for term in self.appearance(estimates, targets):
            # Each view's term is a mean over equally many values, so their sum is 2x the joint mean.
            appearance = appearance + 2 * term
        total = appearance + cfg.smoothness_weight * smoothness + cfg.lr_weight * lr
        return {"total": total, "appearance": appearance, "smoothness": smoothness, "lr_consistency": lr}
