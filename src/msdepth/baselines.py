"""Image-blind baselines a trained network must beat: a constant and a per-pixel prior.

Both are built from the training frames' GT disparity only and never look at a test image,
so a variant that does not beat them has learned the average scene, not depth from the image.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Sequence

import numpy as np
from tqdm import tqdm

from .data import kitti
from .data.index import training_gt_path


def training_gt_disparities(left_images: Sequence[Path], progress: bool = True) -> np.ndarray:
    """GT disparity of each training frame as a fraction of its width, NaN where invalid: (N, H, W)."""
    maps = []
    for left in tqdm(left_images, desc="training GT", disable=not progress, leave=False):
        disp = kitti.read_disparity(training_gt_path(Path(left)))
        frac = disp / disp.shape[1]
        frac[disp <= 0] = np.nan
        maps.append(frac)
    shapes = {m.shape for m in maps}
    if len(shapes) != 1:
        raise ValueError(f"training GT maps differ in size: {sorted(shapes)}")
    return np.stack(maps)


def constant_prior(gt: np.ndarray) -> float:
    """Median valid training disparity (fraction of width)."""
    return float(np.nanmedian(gt))


def per_pixel_prior(gt: np.ndarray) -> np.ndarray:
    """Per-pixel median of the valid training disparities; pixels never valid get the global median."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pixels (sky) are expected
        prior = np.nanmedian(gt, axis=0)
    prior[np.isnan(prior)] = constant_prior(gt)
    return prior.astype(np.float32)


def baseline_disparities(gt: np.ndarray, num_frames: int) -> dict[str, np.ndarray]:
    """Predictions of both baselines for ``num_frames`` frames, in the layout of inference output."""
    prior = per_pixel_prior(gt)
    return {
        "constant": np.full((num_frames, *prior.shape), constant_prior(gt), dtype=np.float32),
        "prior": np.broadcast_to(prior, (num_frames, *prior.shape)).copy(),
    }
