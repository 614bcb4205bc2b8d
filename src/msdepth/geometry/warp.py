"""Horizontal 1-D bilinear warping of an image by a disparity map (Monodepth's bilinear sampler).

Disparities are a *fraction of image width* at every scale (what the network's ``0.3·sigmoid``
heads output), so the same value means the same relative shift at 1/1 and 1/8 resolution.
Monodepth reconstructs the left view with ``warp(right, -disp_left)`` and the right view with
``warp(left, +disp_right)``.
"""

from __future__ import annotations

from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

PaddingMode = Literal["border", "zeros"]


def warp(image: Tensor, disparity: Tensor, padding_mode: PaddingMode = "border") -> Tensor:
    """Sample ``image`` horizontally at ``x + disparity·W``: ``out[..., y, x] = image[..., y, x + d·W]``.

    Args:
        image: (B, C, H, W) tensor to sample from.
        disparity: (B, 1, H, W) horizontal offset as a fraction of the width ``W``.
        padding_mode: what samples outside the image read. ``"border"`` replicates the edge
            column (Monodepth2); ``"zeros"`` fades to 0 over one pixel (Monodepth).

    Returns:
        The warped (B, C, H, W) tensor, differentiable w.r.t. both ``image`` and ``disparity``.

    Raises:
        ValueError: an image that is not 4-D, a disparity not (B, 1, H, W), or an unknown
            ``padding_mode``.

    Example:
        >>> import torch
        >>> image = torch.arange(4.0).reshape(1, 1, 1, 4)
        >>> warp(image, torch.full((1, 1, 1, 4), 0.25))  # 0.25 of 4 px: each pixel reads its right neighbour
        tensor([[[[1., 2., 3., 3.]]]])
        >>> warp(image, torch.full((1, 1, 1, 4), 0.25), padding_mode="zeros")
        tensor([[[[1., 2., 3., 0.]]]])
        >>> warp(image, torch.full((1, 1, 1, 4), 0.125))  # half a pixel: bilinear
        tensor([[[[0.5000, 1.5000, 2.5000, 3.0000]]]])
    """
    if image.dim() != 4:
        raise ValueError(f"warp: image must be (B, C, H, W), got shape {tuple(image.shape)}")
    b, _, h, w = image.shape
    if disparity.shape != (b, 1, h, w):
        raise ValueError(
            f"warp: disparity must be (B, 1, H, W) = {(b, 1, h, w)} to match the image, "
            f"got {tuple(disparity.shape)}"
        )
    if padding_mode not in ("border", "zeros"):
        raise ValueError(f"warp: padding_mode must be 'border' or 'zeros', got {padding_mode!r}")

    # align_corners=True maps pixel x to 2x/(W-1) - 1, so a shift of d·W pixels is 2·d·W/(W-1)
    # in normalised units. With W == 1 every sample lands on the single column anyway.
    scale = 2.0 * w / max(w - 1, 1)
    xs = torch.linspace(-1.0, 1.0, w, dtype=image.dtype, device=image.device)
    ys = torch.linspace(-1.0, 1.0, h, dtype=image.dtype, device=image.device)
    grid_x = xs.view(1, 1, w) + scale * disparity[:, 0].to(image.dtype)
    # A NaN coordinate crashes grid_sample's CPU backward in border mode (torch 2.13: NaN
    # survives its clipping and becomes an out-of-range index, a segfault), e.g. in the steps a
    # GPU run trains on after a NaN loss, before it reads the loss (train.sync_every); ±inf gives
    # NaN samples in zeros mode. Non-finite coordinates go to ±3, outside the image in both
    # modes. In place and untracked: finite values are untouched and their gradient is the
    # identity either way, and the backward gets no extra kernels.
    with torch.no_grad():
        grid_x.nan_to_num_(nan=3.0, posinf=3.0, neginf=-3.0)
    # Rows are sampled exactly at their own centres: bilinear in y degenerates to a copy.
    grid_y = ys.view(1, h, 1).expand(b, h, w)
    grid = torch.stack((grid_x, grid_y), dim=-1)
    return F.grid_sample(image, grid, mode="bilinear", padding_mode=padding_mode, align_corners=True)
