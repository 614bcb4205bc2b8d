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
    """Depth (m) = focal * baseline / disparity; pixels with disparity <= 0 get depth 0 (invalid)."""
    disp_px = np.asarray(disp_px, dtype=np.float32)
    depth = np.zeros_like(disp_px)
    valid = disp_px > 0
    depth[valid] = focal * baseline / disp_px[valid]
    return depth


def clamp_depth(depth: np.ndarray, min_depth: float, max_depth: float) -> np.ndarray:
    """Clamp predicted depth to [min_depth, max_depth] as Monodepth's KITTI-2015 evaluation does."""
    out = depth.copy()
    out[out < min_depth] = min_depth
    out[out > max_depth] = max_depth
    return out
