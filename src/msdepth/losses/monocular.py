"""Monodepth2's monocular (M) and mono+stereo (MS) training loss, with a registered appearance term.

Per scale, the disparity is upsampled to the input size (full-resolution multi-scale), turned
into depth (:func:`msdepth.geometry.camera.disp_to_depth`), and every source frame is reprojected into
the target view with its pose (:func:`msdepth.geometry.camera.reproject`). In MS the stereo partner is
one more source, with its fixed stereo pose.

Per pixel, the candidate with the smallest Monodepth2 reprojection error (``0.85·(1 - SSIM)/2 +
0.15·L1``, 3x3 SSIM with reflection padding, :func:`_reprojection_error`) is chosen among the
reprojected sources and, with auto-masking, the unwarped sources themselves (a pixel that the
identity explains best is static relative to the camera, and learns nothing). The chosen pixels
make one composite reconstruction per scale, and the variant's appearance term
(:mod:`msdepth.losses.appearance`) is called on the composites against the target exactly as the stereo
loss calls it, so every variant, MS-SSIM included (a per-image value, no per-pixel map), plugs in
unchanged. With a per-pixel term (L1) this is Monodepth2's ``mean(min_s error_s)`` exactly; a
windowed term sees windows that straddle a change of chosen source.

Monodepth2 breaks ties with random noise of 1e-5 on the identity errors; here a constant 1e-5
(:data:`IDENTITY_TIE_BREAK`) does, so a tie goes to the reprojection and the loss is deterministic.
"""

from __future__ import annotations

from typing import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from msdepth.config.params import Params
from msdepth.geometry.camera import MAX_DEPTH, MIN_DEPTH, disp_to_depth, reproject, stereo_pose
from msdepth.geometry.warp import PaddingMode
from msdepth.losses.appearance import build_appearance
from msdepth.losses.monodepth import AppearanceTerm, scale_pyramid, smoothness_loss
from msdepth.losses.ssim import ssim
from msdepth.networks.pose import PoseNet, relative_pose

IDENTITY_TIE_BREAK = 1e-5
SMOOTHNESS_WEIGHT = 1e-3  # Monodepth2's
MEAN_EPS = 1e-7  # Monodepth2's, in the mean normalisation of the disparity


def _reprojection_error(estimate: Tensor, target: Tensor, alpha: float = 0.85) -> Tensor:
    """Monodepth2's per-pixel photometric error, (B, 1, H, W): ``alpha·clip((1 - SSIM)/2, 0, 1) +
    (1 - alpha)·|estimate - target|``, both averaged over channels, 3x3 SSIM, reflection padding."""
    dissimilarity = ((1 - ssim(estimate, target, 3, padding="reflect")) / 2).clamp(0, 1)
    l1 = (estimate - target).abs()
    return (alpha * dissimilarity + (1 - alpha) * l1).mean(1, keepdim=True)


def _minimum_reprojection(
    target: Tensor, reconstructions: Sequence[Tensor], identities: Sequence[Tensor] = ()
) -> tuple[Tensor, Tensor]:
    """Per pixel, the candidate with the smallest :func:`_reprojection_error` against ``target``.

    Args:
        reconstructions: the target view reprojected from each source, (B, C, H, W) each.
        identities: the unwarped sources for auto-masking (none: no auto-masking); their errors
            get :data:`IDENTITY_TIE_BREAK` added.

    Returns:
        ``(composite, masked)``: the (B, C, H, W) image of chosen pixels (differentiable through the
        chosen reconstruction) and the (B, 1, H, W) boolean map of pixels an identity won.
    """
    if not reconstructions:
        raise ValueError("minimum_reprojection: needs at least one reconstruction")
    candidates = torch.stack([*identities, *reconstructions], dim=1)  # (B, N, C, H, W)
    if candidates.shape[2:] != target.shape[1:] or candidates.shape[0] != target.shape[0]:
        raise ValueError(
            f"minimum_reprojection: candidates {tuple(candidates.shape)} do not match "
            f"target {tuple(target.shape)}"
        )
    with torch.no_grad():  # the choice is not differentiated, as torch.min's index in Monodepth2
        errors = torch.cat([_reprojection_error(c, target) for c in candidates.unbind(1)], dim=1)
        errors[:, : len(identities)] += IDENTITY_TIE_BREAK
        choice = errors.argmin(dim=1, keepdim=True)  # (B, 1, H, W)
    index = choice.unsqueeze(2).expand(-1, -1, target.shape[1], -1, -1)
    composite = candidates.gather(1, index).squeeze(1)
    return composite, choice < len(identities)


class MonocularLoss(nn.Module):
    """Monodepth2's loss: minimum reprojection over sources with auto-masking, full-resolution
    multi-scale, edge-aware smoothness of the mean-normalised disparity.

    ``appearance`` is the variant's term (:func:`msdepth.losses.appearance.build_appearance`), a child
    module, so trainable state (learned MS-SSIM weights) reaches the optimiser.
    """

    def __init__(
        self,
        appearance: AppearanceTerm,
        smoothness_weight: float = SMOOTHNESS_WEIGHT,
        automask: bool = True,
        min_depth: float = MIN_DEPTH,
        max_depth: float = MAX_DEPTH,
        padding_mode: PaddingMode = "border",
    ) -> None:
        super().__init__()
        if not isinstance(appearance, AppearanceTerm):
            raise TypeError(f"MonocularLoss: appearance must be an AppearanceTerm, got {type(appearance)}")
        self.appearance = appearance
        self.smoothness_weight, self.automask = smoothness_weight, automask
        self.min_depth, self.max_depth, self.padding_mode = min_depth, max_depth, padding_mode

    def forward(
        self,
        disps: Sequence[Tensor],
        target: Tensor,
        sources: Sequence[Tensor],
        poses: Sequence[Tensor],
        k: Tensor,
        inv_k: Tensor,
    ) -> dict[str, Tensor]:
        """Loss terms for one batch.

        Args:
            disps: per scale (fine -> coarse), (B, 1, h_s, w_s) sigmoid outputs in [0, 1].
            target: the (B, 3, H, W) frame whose depth is predicted.
            sources: the (B, 3, H, W) source frames (temporal neighbours; in MS also the partner).
            poses: per source, the (B, 4, 4) pose from the target camera to that source's.
            k, inv_k: (B, 4, 4) intrinsics at H x W and their inverse.

        Returns:
            ``"appearance"`` (the variant's term of each scale's composite, averaged over
            scales), ``"smoothness"`` (sum over scales of the term / 2**s, averaged over scales),
            ``"automask"`` (share of pixels an identity won, over scales) and ``"total"`` =
            appearance + smoothness_weight·smoothness, as Monodepth2 sums and divides by scales.
        """
        if len(sources) != len(poses) or not sources:
            raise ValueError(
                f"MonocularLoss: need one pose per source (>= 1), got {len(sources)} and {len(poses)}"
            )
        h, w = target.shape[-2:]
        identities = list(sources) if self.automask else []
        colours = scale_pyramid(target, len(disps))
        composites, masked = [], target.new_zeros(())
        smoothness = target.new_zeros(())
        for s, disp in enumerate(disps):
            if disp.dim() != 4 or disp.shape[1] != 1 or disp.shape[-2:] != colours[s].shape[-2:]:
                raise ValueError(
                    f"MonocularLoss: scale {s} disparity must be (B, 1, {colours[s].shape[-2]}, "
                    f"{colours[s].shape[-1]}), got {tuple(disp.shape)}"
                )
            full = F.interpolate(disp, size=(h, w), mode="bilinear", align_corners=False)
            depth = disp_to_depth(full, self.min_depth, self.max_depth)[1]
            warped = [
                reproject(src, depth, k, inv_k, pose, self.padding_mode)
                for src, pose in zip(sources, poses, strict=True)
            ]
            composite, won = _minimum_reprojection(target, warped, identities)
            composites.append(composite)
            masked = masked + won.to(target.dtype).mean()
            normalised = disp / (disp.mean((2, 3), keepdim=True) + MEAN_EPS)
            smoothness = smoothness + smoothness_loss(normalised, colours[s]) / 2**s
        n = len(disps)
        appearance = torch.stack(self.appearance(composites, [target] * n)).sum() / n
        smoothness = smoothness / n
        total = appearance + self.smoothness_weight * smoothness
        return {"total": total, "appearance": appearance, "smoothness": smoothness, "automask": masked / n}


def monocular_losses(
    depth_net: nn.Module,
    pose_net: PoseNet,
    criterion: MonocularLoss,
    target: Tensor,
    neighbours: dict[int, Tensor],
    k: Tensor,
    partner: Tensor | None = None,
    side: str | Tensor = "l",
) -> dict[str, Tensor]:
    """One batch of Monodepth2's M (``partner`` None) or MS training: the target's disparities
    (``depth_net``: image -> sigmoid disparities, finest first), the pose of every neighbour (by
    frame offset) from ``pose_net``, and in MS the stereo partner with :func:`_partner_pose`."""
    disps = depth_net(target)
    sources = list(neighbours.values())
    poses = [relative_pose(pose_net, target, source, offset) for offset, source in neighbours.items()]
    if partner is not None:
        sources.append(partner)
        poses.append(_partner_pose(side, target))
    return criterion(disps, target, sources, poses, k, torch.linalg.inv(k))


def _partner_pose(side: str | Tensor, target: Tensor) -> Tensor:
    """(B, 4, 4) :func:`stereo_pose` of every target of the batch ``target``: ``side`` is ``l`` or
    ``r`` for all, or per target a (B,) tensor, non-zero for a right camera's frame."""
    batch = target.shape[0]
    if isinstance(side, str):
        return stereo_pose(side, batch, dtype=target.dtype).to(target.device)
    left, right = (stereo_pose(s, batch, dtype=target.dtype).to(target.device) for s in ("l", "r"))
    return torch.where(side.to(target.device).view(-1, 1, 1) != 0, right, left)


def build_monocular_loss(params: Params, variant: str) -> MonocularLoss:
    """Monodepth2's loss (train.mode mono and mono_stereo) with ``variant``'s appearance term and
    Monodepth2's own smoothness weight (1e-3, not loss.smoothness_weight: another normalisation)."""
    return MonocularLoss(build_appearance(params, variant), padding_mode=params.loss.padding_mode)
