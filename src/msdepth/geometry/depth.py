"""Disparity <-> depth, and network output -> pixel disparity at ground-truth resolution."""

from __future__ import annotations

import cv2
import numpy as np


def pixel_disparity(disp_fraction: np.ndarray, height: int, width: int) -> np.ndarray:
    """Network disparity (fraction of width, any size) -> pixels at ``height`` x ``width``.

    As Monodepth's evaluation: bilinear resize to the GT size, then multiply by the GT width.
    """
    resized = cv2.resize(disp_fraction.astype(np.float32), (width, height), interpolation=cv2.INTER_LINEAR)
    return width * resized


def disparity_to_depth(disp_px: np.ndarray, focal: float, baseline: float) -> np.ndarray:
    """Depth (m) = focal * baseline / disparity; pixels with disparity <= 0 get depth 0 (invalid).

    Args:
        disp_px: disparity in px (GT: 0 where there is none).
        focal: focal length in px, at the disparity map's width.
        baseline: stereo baseline in m.

    Returns:
        float32 depth in m, the shape of ``disp_px``; 0 where the disparity is <= 0.

    Example:
        >>> import numpy as np
        >>> disparity_to_depth(np.array([36.0, 0.0]), focal=720.0, baseline=0.5)
        array([10.,  0.], dtype=float32)
    """
    disp_px = np.asarray(disp_px, dtype=np.float32)
    depth = np.zeros_like(disp_px)
    valid = disp_px > 0
    depth[valid] = focal * baseline / disp_px[valid]
    return depth


def predicted_depth(disp_px: np.ndarray, focal: float, baseline: float) -> np.ndarray:
    """A prediction's depth (m) = focal * baseline / disparity; disparity <= 0 is infinitely far.

    Monodepth's evaluation divides without a guard, so a zero disparity (a matcher's sky) becomes
    infinite depth and the cap clamps it to the farthest depth. :func:`disparity_to_depth` is for
    GT, where 0 means "no GT"; clamped, that 0 would read as the nearest depth instead.
    """
    disp_px = np.asarray(disp_px, dtype=np.float32)
    depth = np.full_like(disp_px, np.inf)
    valid = disp_px > 0
    depth[valid] = focal * baseline / disp_px[valid]
    return depth


def depth_to_disparity(depth: np.ndarray, focal: float, baseline: float) -> np.ndarray:
    """Disparity (px, float64) = focal * baseline / depth of depths in m; depth <= 0 gives 0 (no GT,
    as KITTI's disparity maps mark it) and infinite depth 0 px.

    Args:
        depth: depth in m (0 where there is none).
        focal: focal length in px, at the disparity map's width.
        baseline: stereo baseline in m.

    Returns:
        float64 disparity in px, the shape of ``depth``.

    Example:
        >>> import numpy as np
        >>> depth_to_disparity(np.array([10.0, 0.0, np.inf]), focal=720.0, baseline=0.5)
        array([36.,  0.,  0.])
    """
    depth = np.asarray(depth, dtype=np.float64)
    out = np.zeros_like(depth)
    valid = depth > 0
    out[valid] = focal * baseline / depth[valid]
    return out


def clamp_depth(depth: np.ndarray, min_depth: float, max_depth: float) -> np.ndarray:
    """Clamp predicted depth to [min_depth, max_depth] as Monodepth's KITTI-2015 evaluation does."""
    out = depth.copy()
    out[out < min_depth] = min_depth
    out[out > max_depth] = max_depth
    return out
