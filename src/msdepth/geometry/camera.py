"""Camera geometry of monocular training (Monodepth2's ``layers.py``), as plain functions on tensors.

Back-projection of a depth map through the inverse intrinsics, projection through the
intrinsics and a relative pose, the pose network's axis-angle + translation convention, and
the disparity-to-depth scaling of the network's sigmoid output.

Conventions (Monodepth2's): intrinsics ``K`` and poses ``T`` are (B, 4, 4) homogeneous
matrices in pixels of the image they are used with; ``T`` maps points of the target camera to
the source camera; sampling grids are ``grid_sample`` coordinates with ``align_corners=True``
(pixel x at ``2x/(W-1) - 1``), the mapping of :func:`msdepth.geometry.warp.warp`, so a pure
x-translation reprojects exactly as the stereo warp shifts.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from msdepth.geometry.warp import PaddingMode

MIN_DEPTH = 0.1  # m, Monodepth2's disparity-to-depth range
MAX_DEPTH = 100.0
EPS = 1e-7  # Monodepth2's: keeps the axis of a zero rotation and the projection's 1/Z finite


def disp_to_depth(
    disp: Tensor, min_depth: float = MIN_DEPTH, max_depth: float = MAX_DEPTH
) -> tuple[Tensor, Tensor]:
    """A sigmoid output in [0, 1] -> ``(scaled disparity, depth)``, depth in [min_depth, max_depth].

    The disparity is mapped linearly to ``[1/max_depth, 1/min_depth]`` and inverted, so 0 gives
    ``max_depth`` and 1 gives ``min_depth`` (Monodepth2's ``disp_to_depth``).
    """
    if not 0 < min_depth < max_depth:
        raise ValueError(f"disp_to_depth: need 0 < min_depth < max_depth, got {min_depth} and {max_depth}")
    min_disp, max_disp = 1 / max_depth, 1 / min_depth
    scaled = min_disp + (max_disp - min_disp) * disp
    return scaled, 1 / scaled


def _rotation_from_axis_angle(axis_angle: Tensor) -> Tensor:
    """(B, 3) axis-angle vectors (direction = axis, norm = angle in radians) -> (B, 4, 4) rotations.

    Rodrigues' formula, with Monodepth2's ``1e-7`` added to the angle before normalising the
    axis, so a zero vector gives the identity with a finite gradient.
    """
    if axis_angle.dim() != 2 or axis_angle.shape[1] != 3:
        raise ValueError(f"rotation_from_axis_angle: expected (B, 3), got {tuple(axis_angle.shape)}")
    angle = axis_angle.norm(dim=1, keepdim=True)  # (B, 1)
    axis = axis_angle / (angle + EPS)
    cos, sin = torch.cos(angle)[:, :, None], torch.sin(angle)[:, :, None]
    outer = axis[:, :, None] * axis[:, None, :]  # (B, 3, 3): a aᵀ
    x, y, z = axis.unbind(1)
    zero = torch.zeros_like(x)
    cross = torch.stack((zero, -z, y, z, zero, -x, -y, x, zero), 1).view(-1, 3, 3)  # [a]×
    eye = torch.eye(3, dtype=axis_angle.dtype, device=axis_angle.device)
    rotation = cos * eye + sin * cross + (1 - cos) * outer
    return _homogeneous(rotation, axis_angle.new_zeros(axis_angle.shape[0], 3))


def _translation_matrix(translation: Tensor) -> Tensor:
    """(B, 3) translations -> (B, 4, 4) homogeneous matrices ``[I t; 0 1]``."""
    if translation.dim() != 2 or translation.shape[1] != 3:
        raise ValueError(f"translation_matrix: expected (B, 3), got {tuple(translation.shape)}")
    eye = torch.eye(3, dtype=translation.dtype, device=translation.device)
    return _homogeneous(eye.expand(translation.shape[0], 3, 3), translation)


def _homogeneous(rotation: Tensor, translation: Tensor) -> Tensor:
    """(B, 3, 3) and (B, 3) -> (B, 4, 4) ``[R t; 0 1]``."""
    top = torch.cat((rotation, translation[:, :, None]), dim=2)
    bottom = rotation.new_tensor([0.0, 0.0, 0.0, 1.0]).expand(rotation.shape[0], 1, 4)
    return torch.cat((top, bottom), dim=1)


def transformation_from_parameters(axis_angle: Tensor, translation: Tensor, invert: bool = False) -> Tensor:
    """The pose network's output -> (B, 4, 4) pose: ``T·R``, or with ``invert`` its inverse
    ``Rᵀ·T(-t)`` (Monodepth2 inverts the pose predicted for a frame before the target)."""
    rotation = _rotation_from_axis_angle(axis_angle)
    if not invert:
        return _translation_matrix(translation) @ rotation
    return rotation.transpose(1, 2) @ _translation_matrix(-translation)


def stereo_pose(side: str, batch: int, baseline: float = 0.1, dtype: torch.dtype = torch.float32) -> Tensor:
    """(batch, 4, 4) pose from a target camera to its stereo partner, as Monodepth2's ``stereo_T``:
    an x-translation of ``-baseline`` for a left target (``side == "l"``), ``+baseline`` for a right
    one (Monodepth2's 0.1 stands in for KITTI's 0.54 m: it fixes the scale of the depth)."""
    if side not in ("l", "r"):
        raise ValueError(f"stereo_pose: side must be 'l' or 'r', got {side!r}")
    x = -baseline if side == "l" else baseline
    return _translation_matrix(torch.tensor([[x, 0.0, 0.0]], dtype=dtype).expand(batch, 3))


def _pixel_grid(height: int, width: int, like: Tensor) -> Tensor:
    """(3, H·W) homogeneous pixel coordinates ``(x, y, 1)``, row-major (x fastest)."""
    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=like.dtype, device=like.device),
        torch.arange(width, dtype=like.dtype, device=like.device),
        indexing="ij",
    )
    return torch.stack((xs.reshape(-1), ys.reshape(-1), torch.ones_like(xs).reshape(-1)))


def _backproject(depth: Tensor, inv_k: Tensor) -> Tensor:
    """(B, 1, H, W) depth and (B, 4, 4) inverse intrinsics -> (B, 4, H·W) homogeneous camera points
    ``Z · K⁻¹ (x, y, 1)`` (Monodepth2's ``BackprojectDepth``)."""
    if depth.dim() != 4 or depth.shape[1] != 1:
        raise ValueError(f"backproject: depth must be (B, 1, H, W), got {tuple(depth.shape)}")
    b, _, h, w = depth.shape
    rays = inv_k[:, :3, :3] @ _pixel_grid(h, w, depth)
    points = depth.reshape(b, 1, -1) * rays
    return torch.cat((points, torch.ones_like(points[:, :1])), dim=1)


def project(points: Tensor, k: Tensor, pose: Tensor, height: int, width: int) -> Tensor:
    """(B, 4, H·W) camera points seen through ``pose`` and intrinsics ``k`` -> (B, H, W, 2)
    ``grid_sample`` coordinates (``align_corners=True``), Monodepth2's ``Project3D``."""
    camera = (k @ pose)[:, :3, :] @ points
    pixels = camera[:, :2] / (camera[:, 2:3] + EPS)
    pixels = pixels.view(points.shape[0], 2, height, width).permute(0, 2, 3, 1)
    scale = pixels.new_tensor([max(width - 1, 1), max(height - 1, 1)])
    return (pixels / scale - 0.5) * 2


def reproject(
    source: Tensor,
    depth: Tensor,
    k: Tensor,
    inv_k: Tensor,
    pose: Tensor,
    padding_mode: PaddingMode = "border",
) -> Tensor:
    """The target view synthesised from ``source``: each target pixel, back-projected with its
    ``depth`` and moved by ``pose`` (target -> source camera), samples ``source`` bilinearly."""
    h, w = depth.shape[-2:]
    if source.dim() != 4 or source.shape[0] != depth.shape[0] or source.shape[-2:] != (h, w):
        raise ValueError(
            f"reproject: source must be (B, C, H, W) matching depth {tuple(depth.shape)}, "
            f"got {tuple(source.shape)}"
        )
    grid = project(_backproject(depth, inv_k), k, pose, h, w)
    # As in msdepth.geometry.warp: non-finite coordinates (a NaN step) crash grid_sample's CPU backward in
    # border mode, so they go outside the image; finite ones are untouched.
    with torch.no_grad():
        grid.nan_to_num_(nan=3.0, posinf=3.0, neginf=-3.0)
    return F.grid_sample(
        source, grid.to(source.dtype), mode="bilinear", padding_mode=padding_mode, align_corners=True
    )
